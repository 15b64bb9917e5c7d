// One patient: details, home station, prescriptions, session history and progress.

import { CreateKey, api, clearErrors, currentUser, el, fmt, onSubmit, pathId, renderHeader, requireSignIn } from "./api.js";
import { endReasonBadge, stationBadge } from "./badges.js";
import { confirmButton, showSecret } from "./confirm.js";
import { SIDE_WORDS, fillPatientForm, patientBody, setUpPatientForm } from "./patient-form.js";
import { renderProgress } from "./progress.js";
import { setUpReport } from "./report.js";

await requireSignIn();
renderHeader();

const patientId = pathId(2);
// The API shows a therapist only their own patients, and lets only them change one; an
// admin reads. An archived patient is read-only for everyone.
const isTherapist = currentUser()?.role === "therapist";
let patient = null;
const canWrite = () => isTherapist && patient !== null && !patient.archived_at;
const STATION_POLL_MS = 5000;
const SESSION_POLL_MS = 15000;

const $ = (id) => document.getElementById(id);
let exercises = new Map();
let prescriptions = [];
let sessions = [];

const AXIS_WORDS = {
  roll: "Roll (inversion / eversion)",
  pitch: "Pitch (plantar / dorsiflexion)",
  yaw: "Yaw (ab- / adduction)",
};

function exerciseName(kind) {
  return exercises.get(kind)?.name || fmt.exercise(kind);
}

function renderDetails(p) {
  patient = p;
  document.title = `${p.display_name} · Ankle telerehabilitation`;
  $("name").textContent = p.display_name;
  $("crumb-name").textContent = p.display_name;
  const fact = (term, value) => [el("dt", {}, term), el("dd", {}, value)];
  $("details").replaceChildren(
    ...fact("Reference", p.reference || "–"),
    ...fact("Birth year", p.birth_year ?? "–"),
    ...fact("Affected side", SIDE_WORDS[p.affected_side] || "Not recorded"),
    ...fact("Body weight", p.weight_kg != null ? `${fmt.num(p.weight_kg, 1)} kg` : "Not recorded"),
    ...fact("Added", fmt.day(p.created_at)),
    ...fact("Notes", p.notes ? el("span", { class: "pt-notes" }, p.notes) : "–"),
  );
  const note = $("archived-note");
  note.hidden = !p.archived_at;
  note.textContent = p.archived_at
    ? `Archived on ${fmt.day(p.archived_at)}: this record is read-only. Its prescriptions were withdrawn and its stations revoked.`
    : "";
  $("details-actions").replaceChildren(...detailActions(p));
  $("prescribe-link").hidden = !canWrite();
  // Admins provision too; nobody for an archived patient (the API refuses it).
  $("provision").hidden = Boolean(p.archived_at);
}

function detailActions(p) {
  if (!isTherapist) return [];
  if (p.archived_at) {
    const back = el("button", { type: "button", class: "secondary" }, "Unarchive");
    back.addEventListener("click", async () => {
      back.disabled = true;
      try {
        renderDetails(await api(`/patients/${patientId}/unarchive`, { method: "POST" }));
        flash(`${p.display_name} is a current patient again. Prescribe and provision a station to resume.`);
      } catch (e) {
        flash(`Not unarchived: ${e.message}`);
        back.disabled = false;
      }
    });
    return [back];
  }
  const edit = el("button", { type: "button", class: "secondary" }, "Edit details");
  edit.addEventListener("click", () => openEdit(p));
  const archive = confirmButton({
    label: "Archive patient",
    question:
      `Archive ${p.display_name}? Their active prescriptions are withdrawn and their home stations revoked now: ` +
      "each device stops streaming at once and goes back to the clinic. The record stays, read-only.",
    yes: "Yes, archive",
    no: "Keep as is",
    action: async () => {
      const done = await api(`/patients/${patientId}/archive`, { method: "POST" });
      await refresh();
      const n = (k, word) => `${k} ${word}${k === 1 ? "" : "s"}`;
      flash(
        `Archived. ${n(done.prescriptions_cancelled.length, "prescription")} withdrawn, ` +
          `${n(done.stations_revoked.length, "station")} revoked.`,
      );
      $("details-title").focus();
    },
  });
  return [edit, archive];
}

function openEdit(p) {
  const form = $("edit-patient");
  clearErrors(form);
  fillPatientForm(form, p);
  form.hidden = false;
  $("details-actions").hidden = true;
  form.elements.display_name.focus();
}

function closeEdit() {
  $("edit-patient").hidden = true;
  $("details-actions").hidden = false;
}

$("edit-cancel").addEventListener("click", () => {
  closeEdit();
  $("details-title").focus();
});

onSubmit($("edit-patient"), async (form) => {
  renderDetails(await api(`/patients/${patientId}`, { method: "PATCH", body: patientBody(form) }));
  closeEdit();
  flash("Details saved.");
  $("details-title").focus();
});

function flash(text) {
  $("flash").textContent = text;
  $("flash").hidden = false;
}

function revokeControl(s) {
  return confirmButton({
    label: "Revoke",
    ariaLabel: `Revoke the station “${s.name}”`,
    question:
      `Revoke “${s.name}”? Its token stops working now: the device stops streaming at once and can no longer ` +
      "fetch exercises or upload sessions (any not yet uploaded stay on the station). This cannot be undone; provision a new station instead.",
    yes: "Yes, revoke",
    no: "Keep it",
    action: async () => {
      await api(`/stations/${s.id}/revoke`, { method: "POST" });
      renderStations(await api(`/stations?patient_id=${patientId}`));
      flash(`The station “${s.name}” is revoked.`);
      $("stations-title").focus();
    },
  });
}

function renderStations(stations) {
  const list = $("stations");
  if (!stations.length) {
    list.replaceChildren(
      el("li", { class: "muted" }, "No home station yet. Provision one, then enter its token in the station's configuration."),
    );
    return;
  }
  list.replaceChildren(
    ...stations.map((s) =>
      el(
        "li",
        { dataset: { stationId: s.id } },
        el("div", { class: "row" }, stationBadge(s), el("strong", {}, s.name),
          s.revoked ? null : el("a", { href: `/app/live/${s.id}` }, "Watch live"),
          s.revoked ? null : revokeControl(s)),
        el("div", { class: "muted small" }, s.last_seen_at ? `Last seen ${fmt.date(s.last_seen_at)}` : "Never connected yet"),
      ),
    ),
  );
}

async function pollStations() {
  try {
    const stations = await api(`/stations?patient_id=${patientId}`);
    // Not while a Revoke is asking for confirmation: the question would vanish under the user.
    if (!$("stations").querySelector("[data-confirming]")) renderStations(stations);
  } catch (e) {
    /* a missed poll is retried; the badges keep their last known state */
  }
  setTimeout(pollStations, STATION_POLL_MS);
}

function showToken(station) {
  showSecret($("token-box"), {
    id: "station-token",
    noun: "token",
    title: `Token for the station “${station.name}”: shown only this once`,
    explain:
      "Enter this token in the home station's configuration now (ANKLE_STATION_TOKEN). " +
      "The server keeps only a fingerprint of it and cannot show it again. " +
      "If it is lost, revoke the station and provision a new one.",
    label: "Station token",
    value: station.token,
    after: $("station-name"),
  });
}

const stationKey = new CreateKey();

onSubmit($("provision"), async (form) => {
  const station = await api(`/patients/${patientId}/stations`, {
    method: "POST",
    body: { name: form.elements.name.value },
    once: stationKey,
  });
  form.reset();
  showToken(station);
  renderStations(await api(`/stations?patient_id=${patientId}`));
});

function targetWords(a) {
  const deg = (v) => `${fmt.num(v, 1)}°`;
  if (a.waveform === "sine") return `Sine ${deg(a.center)} ± ${deg(a.amplitude)} at ${fmt.num(a.frequency, 2)} Hz`;
  if (a.waveform === "ramp") return `Ramp ${deg(a.center)} → ${deg(a.ramp_end)} at ${fmt.num(a.ramp_rate, 1)} °/s`;
  return `Hold at ${deg(a.center)}`;
}

function romWords(a) {
  if (a.rom_low == null && a.rom_high == null) return "Allowed range";
  const side = (v) => (v == null ? "allowed" : `${fmt.num(v, 1)}°`);
  return `${side(a.rom_low)} to ${side(a.rom_high)}`;
}

function axisTable(rx) {
  return el(
    "div",
    { class: "pt-scroll" },
    el(
      "table",
      { class: "pt-axes" },
      el("caption", { class: "sr-only" }, `Settings per axis of ${rx.body.title || exerciseName(rx.body.exercise)}`),
      el(
        "thead",
        {},
        el(
          "tr",
          {},
          el("th", { scope: "col" }, "Axis"),
          // The units are in each value: per radian, and per degree below it.
          el("th", { scope: "col", class: "num" }, "Stiffness K"),
          el("th", { scope: "col", class: "num" }, "Damping B"),
          el("th", { scope: "col" }, "Target ", el("span", { class: "unit" }, "(degrees)")),
          el("th", { scope: "col" }, "Range of motion ", el("span", { class: "unit" }, "(degrees)")),
        ),
      ),
      el(
        "tbody",
        {},
        rx.body.axes.map((a, i) =>
          el(
            "tr",
            {},
            el("th", { scope: "row" }, AXIS_WORDS[a.axis] || a.axis),
            // As the forms write them, per radian and per degree (the server's sessions.sentences).
            el("td", { class: "num" }, rx.impedance_text[i].stiffness, el("span", { class: "pt-per-degree" }, rx.impedance_text[i].stiffness_per_degree)),
            el("td", { class: "num" }, rx.impedance_text[i].damping, el("span", { class: "pt-per-degree" }, rx.impedance_text[i].damping_per_degree)),
            el("td", {}, targetWords(a)),
            el("td", {}, romWords(a)),
          ),
        ),
      ),
    ),
  );
}

function timelineWords(b, totalS) {
  const rest = b.sets > 1 ? `, ${fmt.num(b.rest_s, 0)} s rest between sets` : "";
  return `${b.sets} × ${b.repetitions} repetitions of ${fmt.num(b.repetition_s, 1)} s${rest} (${fmt.duration(totalS)} in all); ${b.sessions_per_week} sessions per week`;
}

function withdrawControl(rx) {
  return confirmButton({
    label: "Withdraw",
    question: "The station stops offering it. Withdraw?",
    yes: "Yes, withdraw",
    no: "Keep it",
    action: async () => {
      await api(`/prescriptions/${rx.id}/cancel`, { method: "POST" });
      await loadPrescriptions();
      renderSessions();
      $("rx-title").focus();
    },
  });
}

function prescriptionCard(rx) {
  const b = rx.body;
  const actions = el("div", { class: "row pt-actions" });
  if (canWrite()) {
    actions.append(
      el("a", { class: "button secondary", href: `/app/patients/${patientId}/prescribe?edit=${rx.id}`, "aria-label": `Edit ${b.title || exerciseName(b.exercise)}` }, "Edit"),
      withdrawControl(rx),
    );
  }
  return el(
    "article",
    { class: "card pt-rx", dataset: { prescriptionId: rx.id }, "aria-label": b.title || exerciseName(b.exercise) },
    el(
      "div",
      { class: "row pt-rx-head" },
      el("h3", {}, b.title || exerciseName(b.exercise)),
      el("span", { class: "badge ok" }, `version ${rx.version}`),
      el("span", { class: "muted small" }, `${exerciseName(b.exercise)} · updated ${fmt.date(rx.updated_at)}`),
    ),
    el("p", {}, timelineWords(b, rx.total_s)),
    axisTable(rx),
    el(
      "p",
      { class: "small muted" },
      `Safety limits: torque ${fmt.num(b.torque_limit, 1)} N·m, force ${fmt.num(b.force_limit, 0)} N.`,
    ),
    b.instructions ? el("p", { class: "pt-instructions" }, el("span", { class: "muted" }, "Patient instructions: "), b.instructions) : null,
    actions,
  );
}

function renderPrescriptions() {
  const active = prescriptions.filter((p) => p.status === "active");
  const earlier = prescriptions.filter((p) => p.status !== "active");
  $("rx-active").replaceChildren(
    ...(active.length ? active.map(prescriptionCard) : [el("p", { class: "muted" }, "No active prescription.")]),
  );
  $("rx-earlier").hidden = !earlier.length;
  $("rx-earlier").querySelector("summary").textContent = `Earlier prescriptions (${earlier.length})`;
  $("rx-earlier-list").replaceChildren(
    el(
      "ul",
      { class: "pt-list" },
      earlier.map((p) =>
        el(
          "li",
          { dataset: { prescriptionId: p.id } },
          el("strong", {}, p.body.title || exerciseName(p.body.exercise)),
          ` · version ${p.version} · `,
          el("span", { class: "badge offline" }, p.status),
          ` · ${fmt.date(p.updated_at)}`,
        ),
      ),
    ),
  );
}

async function loadPrescriptions() {
  prescriptions = await api(`/patients/${patientId}/prescriptions`);
  renderPrescriptions();
}

function sessionRow(s) {
  const rx = prescriptions.find((p) => p.id === s.prescription_id);
  const sum = s.summary || {};
  const reps = sum.repetitions_completed ?? "–";
  const of = sum.repetitions_prescribed ?? "–";
  return el(
    "tr",
    { dataset: { sessionId: s.id } },
    el("td", {}, fmt.date(s.started_at)),
    el("td", {}, rx ? rx.body.title || exerciseName(rx.body.exercise) : "–"),
    el("td", { class: "num" }, fmt.duration(sum.duration_s)),
    el("td", { class: "num" }, `${reps} / ${of}`),
    el("td", {}, endReasonBadge(s.end_reason)),
    el("td", {}, el("a", { href: `/app/sessions/${s.id}`, "aria-label": `Open the session of ${fmt.date(s.started_at)}` }, "Open")),
  );
}

function renderSessions() {
  $("history").tBodies[0].replaceChildren(...sessions.map(sessionRow));
  $("history").hidden = !sessions.length;
  $("history-status").textContent = sessions.length
    ? `${sessions.length} session${sessions.length === 1 ? "" : "s"}, newest first.`
    : "No sessions recorded yet.";
  showProgress();
}

function showProgress() {
  return renderProgress($("progress"), patientId, {
    form: $("progress-filter"),
    name: exerciseName,
    errorBox: $("progress-error"),
    note: $("progress-mdc"),
  });
}

$("progress-filter").addEventListener("submit", (event) => {
  event.preventDefault();
  showProgress();
});

function sessionsKey(list) {
  return list.map((s) => `${s.id}:${s.end_reason}:${s.summary ? 1 : 0}`).join(",");
}

async function pollSessions() {
  try {
    const fresh = await api(`/sessions?patient_id=${patientId}&limit=500`);
    if (sessionsKey(fresh) !== sessionsKey(sessions)) {
      sessions = fresh;
      renderSessions();
    }
  } catch (e) {
    /* retried on the next poll */
  }
  setTimeout(pollSessions, SESSION_POLL_MS);
}

function showFlash() {
  const params = new URLSearchParams(location.search);
  const saved = Number.parseInt(params.get("saved"), 10);
  const rx = prescriptions.find((p) => p.id === saved);
  if (!rx) return;
  const flash = $("flash");
  flash.textContent = `Saved “${rx.body.title || exerciseName(rx.body.exercise)}”, version ${rx.version}. The patient's station fetches it now.`;
  flash.hidden = false;
  history.replaceState(null, "", location.pathname);
}

/** Fetch and draw the patient, their stations and prescriptions (after an archive too). */
async function refresh() {
  const [p, stations, rxs] = await Promise.all([
    api(`/patients/${patientId}`),
    api(`/stations?patient_id=${patientId}`),
    api(`/patients/${patientId}/prescriptions`),
  ]);
  prescriptions = rxs;
  renderDetails(p);
  renderStations(stations);
  renderPrescriptions();
}

async function main() {
  if (patientId === null) throw new Error("no patient in this address");
  $("prescribe-link").href = `/app/patients/${patientId}/prescribe`;
  $("rx-title").tabIndex = -1;
  $("stations-title").tabIndex = -1;
  setUpReport(patientId);
  const [list, library] = await Promise.all([
    api(`/sessions?patient_id=${patientId}&limit=500`),
    api("/exercises"),
    isTherapist ? setUpPatientForm($("edit-patient")) : null,
  ]);
  exercises = new Map(library.map((x) => [x.kind, x]));
  $("progress-kind").append(...library.map((x) => el("option", { value: x.kind }, x.name)));
  sessions = list;
  await refresh();
  renderSessions();
  showFlash();
  setTimeout(pollStations, STATION_POLL_MS);
  setTimeout(pollSessions, SESSION_POLL_MS);
}

main().catch((e) => {
  $("load-error").textContent = `This patient's page could not be loaded: ${e.message}`;
  $("load-error").hidden = false;
});
