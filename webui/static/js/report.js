// The patient's report for the medical record: a period and two downloads (the PDF to sign,
// the FHIR bundle for the record system). The server names the files and checks the dates
// (a period that ends after today is refused there); the page only relays its sentences.
// The days are the therapist's own, and so is the report's clock: the page names their time
// zone, else the server counts UTC days and a late-evening session falls on another one.

import { clearErrors, download, showErrors } from "./api.js";

const DEFAULT_DAYS = 90; // as the server's default period

/** The day ``d`` falls on where the therapist is (their computer's calendar), YYYY-MM-DD:
 * not the UTC day, which is yesterday or tomorrow for part of every day away from UTC. */
function isoDay(d) {
  const two = (n) => String(n).padStart(2, "0");
  return `${d.getFullYear()}-${two(d.getMonth() + 1)}-${two(d.getDate())}`;
}

/** Wire the form `#report` for the patient `patientId`. */
export function setUpReport(patientId) {
  const form = document.getElementById("report");
  const status = document.getElementById("report-status");
  const since = form.elements.since;
  const until = form.elements.until;
  const today = new Date();
  until.value = isoDay(today);
  // By the calendar, not by 24-hour steps: a change to or from summer time is no day less.
  since.value = isoDay(new Date(today.getFullYear(), today.getMonth(), today.getDate() - (DEFAULT_DAYS - 1)));
  // The date picker offers no later day; the server refuses one (server/routes/reports.py).
  until.max = since.max = isoDay(today);

  for (const button of form.querySelectorAll("button[data-report]")) {
    button.addEventListener("click", async () => {
      const label = button.dataset.label;
      const query = new URLSearchParams();
      if (since.value) query.set("since", since.value);
      if (until.value) query.set("until", until.value);
      const zone = Intl.DateTimeFormat().resolvedOptions().timeZone;
      if (zone) query.set("tz", zone);
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
