// The therapist's patients: who they are, whether their station is online, when they last
// exercised; and a form to add one.

import { CreateKey, api, currentUser, el, fmt, onSubmit, renderHeader, requireSignIn } from "./api.js";
import { attentionBadge, endReasonBadge, stationBadge } from "./badges.js";
import { SIDE_WORDS, patientBody, setUpPatientForm } from "./patient-form.js";

await requireSignIn();
renderHeader();

const table = document.getElementById("patients");
const listStatus = document.getElementById("list-status");
const loadError = document.getElementById("load-error");
const form = document.getElementById("add-patient");
const added = document.getElementById("added");
// ?archived=true lists the archived patients (read-only records) instead of the current ones.
const archived = new URLSearchParams(location.search).get("archived") === "true";

function stationCell(stations) {
  if (!stations.length) return el("span", { class: "muted" }, "None provisioned");
  return stations.map((s) =>
    el("div", { class: "pt-station" }, stationBadge(s), " ", el("span", { class: "small" }, s.name)),
  );
}

function lastSessionCell(session) {
  if (!session) return el("span", { class: "muted" }, "No sessions yet");
  return el(
    "span",
    {},
    el("a", { href: `/app/sessions/${session.id}` }, fmt.date(session.started_at)),
    " ",
    endReasonBadge(session.end_reason),
  );
}

async function lastSessions(patients) {
  // One small request per patient: "newest first, limit 1" is exact however many sessions
  // the others have, where one shared list would have to guess a page size.
  const lists = await Promise.all(
    patients.map((p) => api(`/sessions?patient_id=${p.id}&limit=1`)),
  );
  return new Map(patients.map((p, i) => [p.id, lists[i][0] ?? null]));
}

/** What needs attention across the therapist's patients, each item linking to its page. */
async function loadAttention() {
  const box = document.getElementById("attention");
  const status = document.getElementById("attention-status");
  const items = await api("/patients/attention");
  box.replaceChildren(
    ...items.map((item) =>
      el(
        "li",
        { dataset: { kind: item.kind, patientId: item.patient_id } },
        attentionBadge(item.kind),
        " ",
        el("strong", {}, item.patient_name),
        item.at ? el("span", { class: "muted small" }, ` ${fmt.date(item.at)}`) : null,
        " ",
        el("span", {}, item.text),
        " ",
        el("a", { href: item.link }, item.session_id ? "Review the session" : `Open ${item.patient_name}'s page`),
      ),
    ),
  );
  status.textContent = items.length
    ? `${items.length} item${items.length === 1 ? "" : "s"} from the last seven days.`
    : "Nothing needs your attention: no faults, holds, early ends, missed sessions or quiet stations in the last seven days.";
}

async function loadList() {
  const [patients, stations] = await Promise.all([
    api(`/patients?archived=${archived}`),
    api("/stations"),
  ]);
  const last = await lastSessions(patients);
  const byPatient = new Map();
  for (const s of stations) {
    if (s.revoked) continue;
    if (!byPatient.has(s.patient_id)) byPatient.set(s.patient_id, []);
    byPatient.get(s.patient_id).push(s);
  }
  const rows = patients.map((p) =>
    el(
      "tr",
      { dataset: { patientId: p.id } },
      el("th", { scope: "row" }, el("a", { href: `/app/patients/${p.id}` }, p.display_name)),
      el("td", {}, p.reference || el("span", { class: "muted" }, "–")),
      el("td", {}, SIDE_WORDS[p.affected_side] || el("span", { class: "muted" }, "Not recorded")),
      el("td", {}, stationCell(byPatient.get(p.id) || [])),
      el("td", {}, lastSessionCell(last.get(p.id))),
    ),
  );
  table.tBodies[0].replaceChildren(...rows);
  table.hidden = !patients.length;
  const count = `${patients.length} ${archived ? "archived " : ""}patient${patients.length === 1 ? "" : "s"}.`;
  listStatus.textContent = patients.length
    ? count
    : archived
      ? "No archived patients."
      : "No patients yet. Add your first patient with the form below.";
}

function showWhichList() {
  const link = document.getElementById("other-list");
  if (!archived) return;
  document.getElementById("attention-section").hidden = true;
  document.title = "Archived patients · Ankle telerehabilitation";
  document.querySelector("h1").textContent = "Archived patients";
  document.getElementById("list-title").textContent = "Your archived patients";
  document.getElementById("add-section").hidden = true;
  link.href = "/app/patients";
  link.textContent = "Back to current patients";
}

async function setUpForm() {
  const user = currentUser();
  if (user && user.role !== "therapist") {
    // The API lets only a therapist add patients (they become theirs).
    document.getElementById("add-section").replaceChildren(
      el("p", { class: "muted" }, "Only a therapist can add patients; an administrator sees them read-only."),
    );
    return;
  }
  await setUpPatientForm(form);
}

const createKey = new CreateKey();

onSubmit(form, async () => {
  added.textContent = "";
  const patient = await api("/patients", { method: "POST", body: patientBody(form), once: createKey });
  form.reset();
  await loadList();
  added.replaceChildren(
    `Added “${patient.display_name}”. `,
    el("a", { href: `/app/patients/${patient.id}` }, "Open their page"),
  );
});

async function main() {
  showWhichList();
  try {
    await Promise.all([loadList(), setUpForm(), archived ? null : loadAttention()]);
  } catch (e) {
    loadError.textContent = `The patient list could not be loaded: ${e.message}`;
    loadError.hidden = false;
    listStatus.textContent = "";
  }
}

main();
