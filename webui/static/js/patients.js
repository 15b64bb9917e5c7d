// The therapist's patients: who they are, whether their station is online, when they last
// exercised; and a form to add one.

import { api, clearErrors, currentUser, el, fmt, renderHeader, requireSignIn, showErrors } from "./api.js";
import { applyBounds, loadSchemas, prop } from "./schema.js";
import { endReasonBadge, stationBadge } from "./badges.js";

await requireSignIn();
renderHeader();

const table = document.getElementById("patients");
const listStatus = document.getElementById("list-status");
const loadError = document.getElementById("load-error");
const form = document.getElementById("add-patient");
const added = document.getElementById("added");

const SIDE_WORDS = { left: "Left", right: "Right", both: "Both" };

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

async function loadList() {
  const [patients, stations] = await Promise.all([api("/patients"), api("/stations")]);
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
  listStatus.textContent = patients.length
    ? `${patients.length} patient${patients.length === 1 ? "" : "s"}.`
    : "No patients yet. Add your first patient with the form below.";
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
  const schemas = await loadSchemas();
  for (const name of ["display_name", "reference", "birth_year", "notes"]) {
    applyBounds(form.elements[name], prop(schemas, "PatientCreate", name));
  }
  // The API refuses a birth year in the future; "now" is the one bound it cannot publish.
  form.elements.birth_year.max = String(new Date().getFullYear());
  const sides = form.elements.affected_side;
  for (const side of prop(schemas, "PatientCreate", "affected_side").enum) {
    sides.append(el("option", { value: side }, SIDE_WORDS[side] || side));
  }
}

function formBody() {
  const f = form.elements;
  const text = (v) => (v.trim() === "" ? null : v.trim());
  const year = f.birth_year.value.trim();
  return {
    display_name: f.display_name.value,
    reference: text(f.reference.value),
    // A number input holding text reads as "": send what was typed so the API says why.
    birth_year: year === "" ? (f.birth_year.validity.badInput ? "not a number" : null) : Number(year),
    affected_side: f.affected_side.value || null,
    notes: f.notes.value,
  };
}

form.addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const button = form.querySelector("button[type=submit]");
  button.disabled = true;
  added.textContent = "";
  clearErrors(form);
  try {
    const patient = await api("/patients", { method: "POST", body: formBody() });
    form.reset();
    await loadList();
    added.replaceChildren(
      `Added “${patient.display_name}”. `,
      el("a", { href: `/app/patients/${patient.id}` }, "Open their page"),
    );
  } catch (e) {
    showErrors(form, e);
  } finally {
    button.disabled = false;
  }
});

async function main() {
  try {
    await Promise.all([loadList(), setUpForm()]);
  } catch (e) {
    loadError.textContent = `The patient list could not be loaded: ${e.message}`;
    loadError.hidden = false;
    listStatus.textContent = "";
  }
}

main();
