// The patient's report for the medical record: a period and two downloads (the PDF to sign,
// the FHIR bundle for the record system). The server names the files and checks the dates.

import { clearErrors, download, showErrors } from "./api.js";

const DEFAULT_DAYS = 90; // as the server's default period

function isoDay(d) {
  return d.toISOString().slice(0, 10);
}

/** Wire the form `#report` for the patient `patientId`. */
export function setUpReport(patientId) {
  const form = document.getElementById("report");
  const status = document.getElementById("report-status");
  const since = form.elements.since;
  const until = form.elements.until;
  const today = new Date();
  until.value = isoDay(today);
  since.value = isoDay(new Date(today.getTime() - (DEFAULT_DAYS - 1) * 86400000));

  for (const button of form.querySelectorAll("button[data-report]")) {
    button.addEventListener("click", async () => {
      const label = button.dataset.label;
      const query = new URLSearchParams();
      if (since.value) query.set("since", since.value);
      if (until.value) query.set("until", until.value);
      clearErrors(form);
      button.disabled = true;
      status.textContent = `Preparing the ${label}…`;
      try {
        const name = await download(`/patients/${patientId}/${button.dataset.report}?${query}`);
        status.textContent = `The ${label} was saved as ${name}.`;
      } catch (e) {
        status.textContent = "";
        showErrors(form, e);
      } finally {
        button.disabled = false;
      }
    });
  }
}
