// The live session: what the patient is doing first (exercise, repetition, angle, torque, K and
// B in force, HOLD/Resume/Stop), live stiffness and damping changes answered by the device's
// own ACK or NACK, charts and the 3D view (viser, in an iframe); the engineering detail (links,
// timing, overruns, leg pressures) under a "Technical" disclosure whose state is remembered.
import { api, ApiError, clearErrors, el, fmt, loginUrl, numberValue, pathId, RAD2DEG, renderHeader, requireSignIn, showErrors, signOut, token } from "./api.js";
import { AXES, AXIS_INDEX } from "./axes.js";

await requireSignIn();
renderHeader();

const stationId = pathId(2);
const COLOURS = { roll: "#c0392b", pitch: "#1f5fbf", yaw: "#2e8b57" };
const LEG_COLOURS = ["#c0392b", "#e67e22", "#b7950b", "#2e8b57", "#1f5fbf", "#8e44ad"];
const WINDOW_S = 10;

const $ = (id) => document.getElementById(id);
const state = {
  online: false,
  unreachable: "", // why the server cannot tell whether the station is online (the relay is down)
  warning: "", // what the therapist must know while the station is online (its token used twice)
  status: null,
  prescriptions: [],
  activeAxes: AXES,
  limits: { stiffness: Infinity, damping: Infinity },
  pending: new Map(),
  frames: 0,
  rate: 0,
  lastTelemetry: null,
  heardAt: null, // when this page last heard from the server (ms, this browser's clock)
  pendingKB: null, // a change accepted but not yet rendered: { values, when, since }
  retryMs: 1000,
  ended: null, // why the server closed the link for good (signed out, expired...): see END
};

function fail(message) {
  const box = $("page-error");
  box.textContent = message;
  box.hidden = false;
}

// ---- charts (uPlot) ------------------------------------------------------------------------
const buf = { t: [], angle: AXES.map(() => []), target: AXES.map(() => []), torque: AXES.map(() => []), dp: [0, 1, 2, 3, 4, 5].map(() => []) };

function chart(target, series, yLabel) {
  const width = Math.max(280, $(target).clientWidth || 400);
  return new uPlot(
    {
      width,
      height: 220,
      scales: { x: { time: false } },
      legend: { live: false },
      cursor: { show: false },
      axes: [{ label: "device time, s" }, { label: yLabel }],
      series: [{ label: "t" }, ...series],
    },
    [[], ...series.map(() => [])],
    $(target),
  );
}

const charts = {
  angle: chart(
    "chart-angle",
    AXES.flatMap((a) => [
      { label: `${a}`, stroke: COLOURS[a], width: 2 },
      { label: `${a} target`, stroke: COLOURS[a], width: 1, dash: [6, 4] },
    ]),
    "degrees",
  ),
  torque: chart("chart-torque", AXES.map((a) => ({ label: a, stroke: COLOURS[a], width: 2 })), "N·m"),
  pressure: chart(
    "chart-pressure",
    LEG_COLOURS.map((c, i) => ({ label: `leg ${i + 1}`, stroke: c, width: 1.5 })),
    "kPa",
  ),
};

function showActiveAxes(axes) {
  state.activeAxes = axes.length ? axes : AXES;
  AXES.forEach((a, i) => {
    const show = state.activeAxes.includes(a);
    charts.angle.setSeries(1 + 2 * i, { show });
    charts.angle.setSeries(2 + 2 * i, { show });
    charts.torque.setSeries(1 + i, { show });
  });
}

function record(m) {
  buf.t.push(m.t);
  AXES.forEach((a, i) => {
    buf.angle[i].push(m.pose[AXIS_INDEX[a]] * RAD2DEG);
    buf.target[i].push(m.pose_cmd[AXIS_INDEX[a]] * RAD2DEG);
    buf.torque[i].push(m.wrench[AXIS_INDEX[a]]);
  });
  for (let leg = 0; leg < 6; leg++) buf.dp[leg].push((m.pressures[2 * leg] - m.pressures[2 * leg + 1]) / 1000);
  while (buf.t.length && buf.t[0] < m.t - WINDOW_S) {
    buf.t.shift();
    for (const group of [buf.angle, buf.target, buf.torque, buf.dp]) for (const s of group) s.shift();
  }
  if (buf.t.length > 1 && buf.t[buf.t.length - 2] > m.t) {
    // Device time went back (the platform restarted): start the window afresh.
    for (const arr of [buf.t, ...buf.angle, ...buf.target, ...buf.torque, ...buf.dp]) arr.splice(0, arr.length - 1);
  }
}

let drawQueued = false;
function drawSoon() {
  if (drawQueued) return;
  drawQueued = true;
  // At most one redraw per animation frame however fast telemetry comes.
  requestAnimationFrame(() => {
    drawQueued = false;
    showNewest();
    charts.angle.setData([buf.t, ...AXES.flatMap((_, i) => [buf.angle[i], buf.target[i]])]);
    charts.torque.setData([buf.t, ...buf.torque]);
    charts.pressure.setData([buf.t, ...buf.dp]);
  });
}

function resizeCharts() {
  for (const [key, c] of Object.entries(charts)) {
    const width = $(`chart-${key}`).clientWidth;
    if (width) c.setSize({ width: Math.max(280, width), height: 220 }); // 0: inside a closed <details>
  }
}
window.addEventListener("resize", resizeCharts);

// ---- status --------------------------------------------------------------------------------
const MODE_CLASS = { ACTIVE: "ok", READY: "ok", HOLD: "warn", HOMING: "warn", FAULT: "bad", ESTOP: "bad" };

function setBadge(node, text, cls) {
  node.textContent = text;
  node.className = `badge ${cls || ""}`;
}

function showLink() {
  const badge = $("st-link");
  if (state.ended) return showEnded();
  if (!linkOpen) setBadge(badge, "server connection lost", "bad");
  else if (state.online && state.warning) setBadge(badge, `station online, but ${state.warning}`, "bad");
  else if (state.online) setBadge(badge, "station online", "online");
  else if (state.unreachable) setBadge(badge, "station not reachable", "bad");
  else setBadge(badge, "station offline", "offline");
  if (!linkOpen) showUnknown(`the connection to the server is lost${lastKnown()}`);
  else if (!state.online) showUnknown(state.unreachable || "the station is not connected");
  else if (!state.status) $("st-doing").textContent = "–"; // online, no status yet
}

// " (last known at 17:20:35: exercising)": what the page last heard, and when.
function lastKnown() {
  if (!state.status || !state.online || state.heardAt === null) return "";
  return ` (last known at ${new Date(state.heardAt).toLocaleTimeString()}: ${doing(state.status)})`;
}

// Offline, out of reach, or with the server's connection lost, the last status and sample are
// not what the patient is doing now: say so rather than show "exercising" and "ACTIVE" for a
// station nobody hears.
function showUnknown(why) {
  $("st-doing").textContent = `unknown: ${why}`;
  showMode("");
  for (const id of ["st-pose", "st-torque"]) $(id).textContent = "–";
}

// Closed for good (signed out, expired, no longer allowed): nothing on the page is news any
// more and nothing can be sent. The last status is cleared rather than left to read as now
// (a red "Held for 2 min" that goes on counting), the controls are greyed, and the page says
// why and what to do (sign in again) instead of "the connection to the server is lost".
function showEnded() {
  const end = state.ended;
  setBadge($("st-link"), end.badge, "offline");
  showUnknown(end.badge);
  state.status = null;
  state.lastTelemetry = null;
  state.pendingKB = null;
  showWhy();
  for (const id of ["st-exercise", "st-progress", "st-rest", "st-message", "st-uploads"]) $(id).textContent = "–";
  for (const a of AXES) {
    const cell = $(`kb-now-${a}`);
    if (!cell) continue;
    cell.textContent = "–"; // "in force" no longer known
    delete cell.dataset.shown;
  }
  for (const node of document.querySelectorAll("#hold, #resume, #stop, #start-form :is(select, button), #kb-form :is(input, button)")) {
    node.disabled = true;
  }
  const box = $("page-error");
  box.replaceChildren(end.text, ...(end.signIn ? [" ", el("a", { href: loginUrl(), id: "sign-in-again" }, "Sign in again")] : []));
  box.hidden = false;
}

function showMode(mode) {
  setBadge($("st-mode"), mode || "–", MODE_CLASS[mode] || "");
}

const clock = (unix) => new Date(unix * 1000).toLocaleTimeString();

// Why the device is held or stopped, from the station's status: also what happened before
// this page was opened (the server's welcome carries the last status).
function showWhy() {
  const s = state.status;
  const banner = $("why");
  let level = "";
  let words = "";
  if (s && s.fault) {
    level = "bad";
    words = `The device stopped: ${s.fault}${s.trip ? ` (trip code ${s.trip})` : ""}.`;
  } else if (s && s.hold) {
    const h = s.hold;
    const held = Math.max(0, Date.now() / 1000 - h.since);
    level = h.patient_may_resume ? "warn" : "bad";
    words = `Held for ${fmt.duration(held)}, since ${clock(h.since)}: ${h.text}.`;
    if (h.ends_at) words += ` Unless resumed, the exercise ends at ${clock(h.ends_at)}.`;
  } else if (s && s.phase === "interrupted") {
    level = "warn";
    words = `The exercise ended: ${s.message || "it was held too long"}.`;
  }
  banner.hidden = !words;
  banner.dataset.level = level;
  if (banner.textContent !== words) banner.textContent = words;
  // No status yet (connecting, or cleared once signed out): not "none", which would say the
  // device is known to be neither faulted nor held.
  $("st-trip").textContent = !s ? "–" : s.fault ? s.fault : s.hold ? `held: ${s.hold.text}` : "none";
}

// What the patient is doing, in a therapist's words, from the station's phase.
const DOING = {
  idle: "not exercising",
  homing: "waiting: the platform is moving to its start position",
  running: "exercising",
  rest: "resting between repetitions",
  paused: "held: the platform stands still",
  done: "finished the exercise",
  stopped: "not exercising: the exercise was stopped",
  fault: "not exercising: the platform stopped on a fault",
  interrupted: "not exercising: the station ended the exercise early",
};

function doing(s) {
  if (s.device_link !== "connected") return "unknown: the platform is not connected to the station";
  return DOING[s.phase] || s.phase;
}

// Sessions waiting at the station, and those the server refused (kept there, not sent again).
function uploadWords(s) {
  const waiting = s.pending_uploads ? `${s.pending_uploads} waiting to be sent` : "none waiting";
  if (!s.refused_uploads) return waiting;
  const named = (s.refused_sessions || []).join("; ");
  return `${waiting}; ${s.refused_uploads} refused by the server, kept at the station: ${named}`;
}

function showStatus(s) {
  state.status = s;
  $("st-device").textContent = s.device_link === "connected" ? "connected" : "lost";
  showMode(s.device_mode);
  showWhy();
  $("st-doing").textContent = doing(s);
  if (!linkOpen || !state.online) showLink(); // not news of now: unknown
  const rx = state.prescriptions.find((p) => p.id === s.prescription_id);
  // The prescription's title, as the therapist named it; its kind only when the page does not
  // hold it (one cancelled since it started).
  $("st-exercise").textContent = !s.exercise ? "none running" : rx?.body.title || fmt.exercise(s.exercise);
  $("st-phase").textContent = s.phase;
  $("st-device-mode").textContent = s.device_mode || "–";
  $("st-progress").textContent = s.sets ? `set ${s.set} of ${s.sets} · repetition ${s.rep} of ${s.repetitions}` : "–";
  $("st-rest").textContent = s.phase === "rest" ? `${Math.ceil(s.rest_remaining_s)} s` : "–";
  $("st-overruns").textContent = String(s.overruns);
  $("st-frames").textContent = String(s.frames_lost);
  $("st-message").textContent = s.message || "–";
  $("st-uploads").textContent = uploadWords(s);
  if (rx) {
    showActiveAxes(rx.body.axes.map((a) => a.axis));
    fillKB(rx.body.axes);
  }
}

// Every sample goes into the charts; the numbers show the newest, once per frame.
function showTelemetry(m) {
  state.frames += 1;
  state.lastTelemetry = m;
  record(m);
  drawSoon();
}

// Numbers a person reads: five times a second is enough, and spares a busy computer the
// layout work of rewriting them on every frame.
const NUMBERS_EVERY_MS = 200;
let numbersAt = 0;

function showNewest() {
  const m = state.lastTelemetry;
  const now = performance.now();
  // Offline or cut off, the newest sample is an old one: the status card says the state is
  // unknown.
  if (!m || !linkOpen || !state.online || now - numbersAt < NUMBERS_EVERY_MS) return;
  numbersAt = now;
  showMode(m.mode);
  $("st-pose").textContent = state.activeAxes.map((a) => `${a} ${fmt.num(m.pose[AXIS_INDEX[a]] * RAD2DEG, 1)}°`).join(" · ");
  $("st-torque").textContent = state.activeAxes.map((a) => `${a} ${fmt.num(m.wrench[AXIS_INDEX[a]], 1)} N·m`).join(" · ");
  const pending = state.pendingKB;
  // Rendered once the device runs the exercise again, on a sample newer than the answer.
  if (pending && m.mode === "ACTIVE" && m.t > pending.since) state.pendingKB = null;
  for (const a of AXES) {
    const cell = $(`kb-now-${a}`);
    if (!cell) continue;
    const inForce = `${fmt.num(m.stiffness[AXIS_INDEX[a]], 1)} · ${fmt.num(m.damping[AXIS_INDEX[a]], 2)}`;
    const next = state.pendingKB && pendingText(state.pendingKB, a);
    if (cell.dataset.shown === inForce + (next || "")) continue;
    cell.dataset.shown = inForce + (next || "");
    cell.replaceChildren(inForce, ...(next ? [el("span", { class: "kb-pending" }, next)] : []));
  }
}

// "→ K 80.0 · B 3.00 on Resume" for an axis a pending change touches, else "".
function pendingText(pending, axis) {
  const k = pending.values.stiffness[axis];
  const b = pending.values.damping[axis];
  if (k === undefined && b === undefined) return "";
  const parts = [k !== undefined ? `K ${fmt.num(k, 1)}` : "", b !== undefined ? `B ${fmt.num(b, 2)}` : ""];
  return `→ ${parts.filter(Boolean).join(" · ")} ${pending.when}`;
}

const APPLIES_WHEN = { on_resume: "on Resume", next_repetition: "from the next repetition" };

setInterval(() => {
  $("st-rate").textContent = state.frames ? `${state.frames} samples/s` : "no samples";
  state.frames = 0;
  const m = state.lastTelemetry;
  // Station clock to this browser's clock: meaningful when both keep network time.
  $("st-age").textContent = m ? `${Math.max(0, Date.now() - m.sent * 1000).toFixed(0)} ms` : "–";
  showWhy(); // the time held goes on between statuses
}, 1000);

function describe(e) {
  const d = e.detail || {};
  if (d.from !== undefined && d.to !== undefined) {
    const extra = [d.text, d.code ? `code ${d.code}` : ""].filter(Boolean).join(", ");
    return `${e.kind}: ${d.from} → ${d.to}${extra ? ` (${extra})` : ""}`;
  }
  if (e.kind === "interrupted" && d.text) return `exercise ended: ${d.text}`;
  if (e.kind === "impedance" && d.old && d.new) {
    const parts = [];
    for (const [what, unit] of [["stiffness", "K"], ["damping", "B"]]) {
      for (const [axis, v] of Object.entries(d.new[what] || {})) {
        const was = (d.old[what] || {})[axis];
        if (was !== v) parts.push(`${axis} ${unit} ${fmt.num(was, 1)} → ${fmt.num(v, 1)}`);
      }
    }
    return `impedance: ${parts.join(", ") || "unchanged"}`;
  }
  const rest = Object.entries(d).map(([k, v]) => `${k} ${typeof v === "object" ? JSON.stringify(v) : v}`);
  return rest.length ? `${e.kind}: ${rest.join(", ")}` : e.kind;
}

function addEvent(ev) {
  const e = ev.event;
  const when = new Date(e.wall * 1000).toLocaleTimeString();
  const list = $("events");
  list.prepend(el("li", {}, `${when} ${describe(e)} (by ${e.by})`));
  while (list.children.length > 50) list.lastChild.remove();
}

// ---- commands ------------------------------------------------------------------------------
let counter = 0;
function requestId() {
  counter += 1;
  return `${Date.now().toString(36)}-${counter}-${Math.random().toString(36).slice(2, 8)}`;
}

function send(action, fields, ackNode, label) {
  const id = requestId();
  state.pending.set(id, { sent: performance.now(), ackNode, label });
  link.postMessage({ op: "send", message: { type: "command", request_id: id, action, ...fields } });
  ackNode.textContent = `${label}: sent, waiting for the device…`;
  ackNode.className = "small";
}

function onResult(r) {
  const p = state.pending.get(r.request_id);
  if (!p) return;
  state.pending.delete(r.request_id);
  const rtt = performance.now() - p.sent;
  $("st-rtt").textContent = `${rtt.toFixed(0)} ms (station to device ${r.rtt_ms.toFixed(0)} ms)`;
  if (r.ok) {
    // The station words the answer by when the device renders a K/B change (now, on Resume
    // from a HOLD, from the next repetition); "In force" shows what is pending until then.
    p.ackNode.textContent = `${p.label}: ${r.text || "accepted"} (${rtt.toFixed(0)} ms)`;
    p.ackNode.className = "small ack-ok";
    const change = r.change;
    if (change && APPLIES_WHEN[change.applies]) {
      const since = state.lastTelemetry ? state.lastTelemetry.t : -Infinity;
      state.pendingKB = { values: change.new, when: APPLIES_WHEN[change.applies], since };
    } else if (change) state.pendingKB = null;
    numbersAt = 0; // show the pending change at the next frame
    drawSoon();
  } else {
    // TIMEOUT: nobody answered, so nothing was refused (the device may have acted). OFFLINE:
    // the command did not reach the device. The code (and the field) stay in data-code for
    // programs; the therapist reads the answer's sentence.
    const how = r.code === "TIMEOUT" ? "no answer" : r.code === "OFFLINE" ? "not done" : "refused";
    p.ackNode.textContent = `${p.label}: ${how}: ${r.text}`;
    p.ackNode.className = "small ack-bad";
  }
  p.ackNode.dataset.code = r.ok ? r.code || "ACK" : r.code;
}

$("hold").addEventListener("click", () => send("hold", {}, $("ack"), "HOLD"));
$("resume").addEventListener("click", () => send("resume", {}, $("ack"), "Resume"));
$("stop").addEventListener("click", () => {
  if (confirm("Stop the exercise now? The platform returns home and the session ends.")) send("stop", {}, $("ack"), "Stop");
});
$("start-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  const id = Number.parseInt($("start-rx").value, 10);
  if (Number.isFinite(id)) send("start", { prescription_id: id }, $("ack"), "Start");
});

// ---- stiffness and damping -----------------------------------------------------------------
function buildKB() {
  const rows = AXES.map((a) =>
    el(
      "tr",
      { id: `kb-row-${a}` },
      el("th", { scope: "row" }, a),
      el(
        "td",
        {},
        el("label", { for: `kb-k-${a}`, class: "sr-only" }, `${a} stiffness K, N·m/rad`),
        el("input", { id: `kb-k-${a}`, type: "number", step: "any", min: 0, max: state.limits.stiffness, "data-field": `stiffness.${a}`, inputmode: "decimal" }),
      ),
      el(
        "td",
        {},
        el("label", { for: `kb-b-${a}`, class: "sr-only" }, `${a} damping B, N·m·s/rad`),
        el("input", { id: `kb-b-${a}`, type: "number", step: "any", min: 0, max: state.limits.damping, "data-field": `damping.${a}`, inputmode: "decimal" }),
      ),
      el("td", { id: `kb-now-${a}`, class: "num" }, "–"),
    ),
  );
  $("kb-rows").replaceChildren(...rows);
}

let filledFor = null;
function fillKB(axes) {
  const key = JSON.stringify(axes);
  if (filledFor === key) return; // never overwrite what the therapist is typing
  filledFor = key;
  for (const a of AXES) {
    const rx = axes.find((x) => x.axis === a);
    $(`kb-row-${a}`).hidden = !rx;
    $(`kb-k-${a}`).value = rx ? rx.stiffness : "";
    $(`kb-b-${a}`).value = rx ? rx.damping : "";
  }
}

$("kb-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  const form = $("kb-form");
  clearErrors(form);
  // The line answers this submission only: an earlier "acknowledged by the device" beside a
  // refusal of new values would read as if they had been applied.
  const ack = $("kb-ack");
  ack.textContent = "";
  ack.className = "small";
  delete ack.dataset.code;
  const stiffness = {};
  const damping = {};
  const errors = [];
  for (const a of state.activeAxes) {
    for (const [kind, out, max, unit] of [
      ["k", stiffness, state.limits.stiffness, "N·m/rad"],
      ["b", damping, state.limits.damping, "N·m·s/rad"],
    ]) {
      // As the prescription form reads a number: text the browser cannot read (1e400, past
      // the largest double, reads as empty) is refused, never taken for a field left blank.
      const v = numberValue($(`kb-${kind}-${a}`));
      if (v === null) continue;
      const field = `${kind === "k" ? "stiffness" : "damping"}.${a}`;
      // Checked here as the server's schema checks it: a message the server refuses closes
      // the live link, so the therapist's typo must never reach it.
      if (typeof v !== "number" || !Number.isFinite(v) || v < 0 || v > max) {
        errors.push({ loc: ["body", ...field.split(".")], msg: `must be a number from 0 to ${max} ${unit}` });
      } else out[a] = v;
    }
  }
  if (errors.length) {
    showErrors(form, new ApiError(422, errors));
    return;
  }
  if (!Object.keys(stiffness).length && !Object.keys(damping).length) {
    ack.textContent = "Enter a stiffness or damping to send.";
    return;
  }
  send("set_impedance", { stiffness, damping }, $("kb-ack"), "Stiffness and damping");
});

// ---- the link (its socket lives in a worker: live-link.js) ----------------------------------
// Closed because trust ended (sessions/wire.py CLOSE_*): retrying cannot help. The badge says
// it in a few words, the text what to do; signIn: signing in again is the way back.
const END = {
  1008: { badge: "not allowed to watch", text: "You may not watch this station (signed out, or not your patient's station).", signIn: true },
  4004: { badge: "signed out", text: "You were signed out. Sign in again to keep watching.", signIn: true },
  4005: { badge: "sign-in expired", text: "Your sign-in expired. Sign in again to keep watching.", signIn: true },
  4006: { badge: "account deactivated", text: "Your account was deactivated. Ask your administrator.", signIn: false },
  4007: { badge: "no longer your patient", text: "You may no longer see this patient, so the live view was closed.", signIn: false },
  4008: { badge: "password must be changed", text: "Your password must be changed before you can watch. Sign in again to change it.", signIn: true },
};

const link = new Worker("/static/js/live-link.js", { type: "module" });
let linkOpen = false;

function onMessage(m) {
  switch (m.type) {
    case "telemetry":
      showTelemetry(m);
      break;
    case "status":
      showStatus(m);
      break;
    case "welcome":
      state.online = m.online;
      state.unreachable = "";
      state.warning = "";
      state.status = null; // what the server knows now; nothing from before the connection
      if (m.status) showStatus(m.status);
      showLink();
      break;
    case "presence":
      state.online = m.online;
      state.unreachable = m.online || m.known !== false ? "" : m.text || "";
      state.warning = m.online && m.warning ? m.text || "" : "";
      showLink();
      if (m.online && state.status) showStatus(state.status);
      break;
    case "event":
      addEvent(m);
      break;
    case "result":
      onResult(m);
      break;
    default:
      break;
  }
}

link.addEventListener("message", (ev) => {
  const m = ev.data;
  if (m.op === "messages") {
    if (linkOpen) state.heardAt = Date.now();
    for (const item of m.items) onMessage(item);
  } else if (m.op === "open") {
    linkOpen = true;
    state.retryMs = 1000;
    showLink();
  } else if (m.op === "unsent") {
    const p = state.pending.get(m.request_id);
    state.pending.delete(m.request_id);
    if (p) {
      const why = state.ended ? state.ended.badge : "the connection to the server is down";
      p.ackNode.textContent = `${p.label}: not sent, ${why}`;
      p.ackNode.className = "small ack-bad";
    }
  } else if (m.op === "close") {
    linkOpen = false;
    state.ended = END[m.code] || null;
    if (m.code === 4004 || m.code === 4005) signOut(); // its token is dead: sign in afresh
    showLink(); // what the patient is doing is unknown from now on
    if (state.ended) {
      // The 3D view's ticket was this sign-in's: it stops with it.
      $("scene").src = "about:blank";
      return;
    }
    const wait = state.retryMs;
    state.retryMs = Math.min(state.retryMs * 2, 10000);
    const why = m.reason ? ` (${m.code}: ${m.reason})` : ` (${m.code})`;
    setBadge($("st-link"), `server connection lost${why}, retrying in ${Math.round(wait / 1000)} s`, "bad");
    setTimeout(() => {
      connect();
      openScene();
    }, wait);
  }
});

function connect() {
  const proto = location.protocol === "https:" ? "wss" : "ws";
  link.postMessage({
    op: "open",
    url: `${proto}://${location.host}/ws/live/${stationId}`,
    protocols: ["ankle.v1", `bearer.${token()}`],
  });
}

// ---- the 3D view -----------------------------------------------------------------------------
// viser's client, on this server's own port behind a ticket for this station. Once open, its
// WebSocket keeps the ticket alive and reconnects by itself; a new ticket is needed only after
// the page lost the server (a restart forgets tickets) or the view was turned off.
const SCENE_KEY = "ankle.live.scene";

function sceneWanted() {
  return localStorage.getItem(SCENE_KEY) !== "off";
}

$("scene-on").checked = sceneWanted();
$("scene-on").addEventListener("change", (ev) => {
  localStorage.setItem(SCENE_KEY, ev.target.checked ? "on" : "off");
  openScene();
});

// Off, the 3D card shrinks to its heading and switch, and the clinical cards take the width.
function showSceneWanted(on) {
  $("live-layout").classList.toggle("scene-off", !on);
  $("scene").hidden = !on;
  resizeCharts();
}

async function openScene() {
  const frame = $("scene");
  const on = sceneWanted();
  showSceneWanted(on);
  if (!on) {
    // about:blank stops the viewer and its connection; the server's view idles out by itself.
    if (frame.getAttribute("src") !== "about:blank") frame.src = "about:blank";
    $("st-scene").textContent = "turned off on this computer";
    return;
  }
  try {
    const t = await api(`/stations/${stationId}/scene/ticket`, { method: "POST" });
    frame.src = t.path;
    $("scene-note").textContent = "";
    $("st-scene").textContent = `viser, through this server at ${t.path.replace(/[^/]+\/$/, "…/")}`;
  } catch (e) {
    $("scene-note").textContent = `The 3D view is not available: ${e.message}`;
    $("st-scene").textContent = `not available: ${e.message}`;
  }
}

showSceneWanted(sceneWanted()); // before the ticket comes: no empty panel meanwhile

// ---- the Technical disclosure: closed unless this computer's therapist opened it -------------
const TECH_KEY = "ankle.live.technical";
$("technical").open = localStorage.getItem(TECH_KEY) === "open";
$("technical").addEventListener("toggle", (ev) => {
  localStorage.setItem(TECH_KEY, ev.target.open ? "open" : "closed");
  if (ev.target.open) resizeCharts(); // the pressure chart had no width while closed
});

// ---- start ---------------------------------------------------------------------------------
async function main() {
  if (stationId === null) return fail("No station in the address.");
  let station;
  try {
    const [stations, schemas] = await Promise.all([api("/stations"), api("/schemas/ws")]);
    station = stations.find((s) => s.id === stationId);
    const command = schemas.viewer_to_server.$defs.Command.properties;
    state.limits.stiffness = command.stiffness.anyOf[0].additionalProperties.maximum;
    state.limits.damping = command.damping.anyOf[0].additionalProperties.maximum;
  } catch (e) {
    return fail(`Cannot load the station: ${e.message}`);
  }
  buildKB();
  if (!station) return fail("No such station, or it is not one of your patients' stations.");
  const patient = await api(`/patients/${station.patient_id}`);
  document.title = `Live: ${patient.display_name} · Ankle telerehabilitation`;
  $("title").textContent = `Live: ${patient.display_name}`;
  $("back").replaceWith(
    el("span", {}, el("a", { href: "/app/patients" }, "Patients"), " › ", el("a", { href: `/app/patients/${patient.id}` }, patient.display_name), ` › ${station.name}`),
  );
  const rxs = await api(`/patients/${patient.id}/prescriptions`);
  state.prescriptions = rxs.filter((p) => p.status === "active");
  $("start-rx").replaceChildren(
    ...state.prescriptions.map((p) => el("option", { value: p.id }, `${p.body.title || fmt.exercise(p.body.exercise)} (v${p.version})`)),
  );
  if (state.status) showStatus(state.status);
  connect();
  openScene();
}

main();
