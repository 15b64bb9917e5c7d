// One patient: details, home station, prescriptions, session history and progress.

import { api, clearErrors, currentUser, el, fmt, pathId, renderHeader, requireSignIn, showErrors } from "./api.js";
import { endReasonBadge, stationBadge } from "./badges.js";
import { renderProgress } from "./progress.js";

await requireSignIn();
renderHeader();

const patientId = pathId(2);
const canWrite = currentUser()?.role === "therapist";
const STATION_POLL_MS = 5000;
const SESSION_POLL_MS = 15000;

const $ = (id) => document.getElementById(id);
let exercises = new Map();
let prescriptions = [];
let sessions = [];

const SIDE_WORDS = { left: "Left", right: "Right", both: "Both" };
const AXIS_WORDS = {
  roll: "Roll (inversion / eversion)",
  pitch: "Pitch (plantar / dorsiflexion)",
  yaw: "Yaw (ab- / adduction)",
};

function exerciseName(kind) {
  return exercises.get(kind)?.name || fmt.exercise(kind);
}

function renderDetails(p) {
  document.title = `${p.display_name} · Ankle telerehabilitation`;
  $("name").textContent = p.display_name;
  $("crumb-name").textContent = p.display_name;
  const fact = (term, value) => [el("dt", {}, term), el("dd", {}, value)];
  $("details").replaceChildren(
    ...fact("Reference", p.reference || "–"),
    ...fact("Birth year", p.birth_year ?? "–"),
    ...fact("Affected side", SIDE_WORDS[p.affected_side] || "Not recorded"),
    ...fact("Added", fmt.day(p.created_at)),
    ...fact("Notes", p.notes ? el("span", { class: "pt-notes" }, p.notes) : "–"),
  );
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
          s.revoked ? null : el("a", { href: `/app/live/${s.id}` }, "Watch live")),
        el("div", { class: "muted small" }, s.last_seen_at ? `Last seen ${fmt.date(s.last_seen_at)}` : "Never connected yet"),
      ),
    ),
  );
}

async function pollStations() {
  try {
    renderStations(await api(`/stations?patient_id=${patientId}`));
  } catch (e) {
    /* a missed poll is retried; the badges keep their last known state */
  }
  setTimeout(pollStations, STATION_POLL_MS);
}

function showToken(station) {
  const box = $("token-box");
  const input = el("input", { id: "station-token", readonly: true, value: station.token, class: "pt-token-value", spellcheck: "false" });
  box.replaceChildren(
    el("h3", {}, `Token for the station “${station.name}”: shown only this once`),
    el(
      "p",
      {},
      "Enter this token in the home station's configuration now (ANKLE_STATION_TOKEN). " +
        "The server keeps only a fingerprint of it and cannot show it again. " +
        "If it is lost, revoke the station and provision a new one.",
    ),
    el("label", { for: "station-token" }, "Station token"),
    input,
    el(
      "div",
      { class: "row pt-token-actions" },
      el("button", { type: "button", class: "secondary", onclick: () => copyToken(input) }, "Copy token"),
      el("button", { type: "button", onclick: () => hideToken(box) }, "I have saved it: hide the token"),
      el("span", { class: "small", role: "status", id: "copy-status" }),
    ),
  );
  box.hidden = false;
  box.focus();
  input.select();
}

function hideToken(box) {
  box.replaceChildren();
  box.hidden = true;
  $("station-name").focus();
}

async function copyToken(input) {
  input.select();
  const status = $("copy-status");
  try {
    await navigator.clipboard.writeText(input.value);
    status.textContent = "Copied.";
  } catch (e) {
    // Clipboard access needs a secure page; the text is selected for Ctrl+C instead.
    status.textContent = "Press Ctrl+C to copy the selected token.";
  }
}

$("provision").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const form = ev.currentTarget;
  const button = form.querySelector("button[type=submit]");
  button.disabled = true;
  clearErrors(form);
  try {
    const station = await api(`/patients/${patientId}/stations`, {
      method: "POST",
      body: { name: form.elements.name.value },
    });
    form.reset();
    showToken(station);
    renderStations(await api(`/stations?patient_id=${patientId}`));
  } catch (e) {
    showErrors(form, e);
  } finally {
    button.disabled = false;
  }
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
          el("th", { scope: "col", class: "num" }, "Stiffness K ", el("span", { class: "unit" }, "(N·m/rad)")),
          el("th", { scope: "col", class: "num" }, "Damping B ", el("span", { class: "unit" }, "(N·m·s/rad)")),
          el("th", { scope: "col" }, "Target ", el("span", { class: "unit" }, "(degrees)")),
          el("th", { scope: "col" }, "Range of motion ", el("span", { class: "unit" }, "(degrees)")),
        ),
      ),
      el(
        "tbody",
        {},
        rx.body.axes.map((a) =>
          el(
            "tr",
            {},
            el("th", { scope: "row" }, AXIS_WORDS[a.axis] || a.axis),
            el("td", { class: "num" }, `${fmt.num(a.stiffness, 1)} N·m/rad`),
            el("td", { class: "num" }, `${fmt.num(a.damping, 2)} N·m·s/rad`),
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

function withdrawControls(rx, slot) {
  const ask = el("button", { type: "button", class: "danger" }, "Withdraw");
  ask.addEventListener("click", () => {
    const keep = el("button", { type: "button", class: "secondary" }, "Keep it");
    const confirm = el("button", { type: "button", class: "danger" }, "Yes, withdraw");
    const error = el("span", { class: "field-error", role: "alert" });
    keep.addEventListener("click", () => {
      slot.replaceChildren(ask);
      ask.focus();
    });
    confirm.addEventListener("click", async () => {
      confirm.disabled = true;
      try {
        await api(`/prescriptions/${rx.id}/cancel`, { method: "POST" });
        await loadPrescriptions();
        renderSessions();
        $("rx-title").focus();
      } catch (e) {
        error.textContent = e.message;
        confirm.disabled = false;
      }
    });
    slot.replaceChildren(
      el("span", {}, "The station stops offering it. Withdraw?"),
      confirm,
      keep,
      error,
    );
    confirm.focus();
  });
  return ask;
}

function prescriptionCard(rx) {
  const b = rx.body;
  const actions = el("div", { class: "row pt-actions" });
  if (canWrite) {
    const slot = el("span", { class: "row" });
    slot.append(withdrawControls(rx, slot));
    actions.append(
      el("a", { class: "button secondary", href: `/app/patients/${patientId}/prescribe?edit=${rx.id}`, "aria-label": `Edit ${b.title || exerciseName(b.exercise)}` }, "Edit"),
      slot,
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
  renderProgress($("progress"), sessions, prescriptions);
}

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

async function main() {
  if (patientId === null) throw new Error("no patient in this address");
  $("prescribe-link").href = `/app/patients/${patientId}/prescribe`;
  $("prescribe-link").hidden = !canWrite;
  $("rx-title").tabIndex = -1;
  const [patient, stations, rxs, list, library] = await Promise.all([
    api(`/patients/${patientId}`),
    api(`/stations?patient_id=${patientId}`),
    api(`/patients/${patientId}/prescriptions`),
    api(`/sessions?patient_id=${patientId}&limit=500`),
    api("/exercises"),
  ]);
  exercises = new Map(library.map((x) => [x.kind, x]));
  prescriptions = rxs;
  sessions = list;
  renderDetails(patient);
  renderStations(stations);
  renderPrescriptions();
  renderSessions();
  showFlash();
  setTimeout(pollStations, STATION_POLL_MS);
  setTimeout(pollSessions, SESSION_POLL_MS);
}

main().catch((e) => {
  $("load-error").textContent = `This patient's page could not be loaded: ${e.message}`;
  $("load-error").hidden = false;
});
