// One recorded session: summary, charts over the whole session (uPlot), the 3D replay
// (viser's recording in viser's own viewer) and the downloads.
import { api, download, el, fmt, pathId, renderHeader, requireSignIn } from "./api.js";
import { endReasonBadge } from "./badges.js";
import { renderMetrics } from "./exercise-metrics.js";

await requireSignIn();
renderHeader();

const sessionId = pathId(2);
const COLOURS = { roll: "#c0392b", pitch: "#1f5fbf", yaw: "#2e8b57" };
const LEG_COLOURS = ["#c0392b", "#e67e22", "#b7950b", "#2e8b57", "#1f5fbf", "#8e44ad"];
const EXERCISE_SHADE = "rgba(31, 95, 191, 0.08)";
const STOP_SHADE = "rgba(179, 38, 30, 0.14)";
const STOP_MODES = new Set(["HOLD", "ESTOP", "FAULT"]);
const FORMATS = [
  ["csv", "CSV", "One row per sample, for spreadsheets"],
  ["parquet", "Parquet", "The same columns at full precision, for analysis"],
  ["mcap", "MCAP", "Telemetry and events for Foxglove and robotics tools"],
  ["json", "JSON", "Header, summary and events, without the samples"],
  ["rec", "REC", "The recording exactly as the home station uploaded it"],
];
const EVENT_NAMES = {
  rep_done: "Repetitions done",
  set_done: "Sets done",
  rest: "Rests",
  mode: "Mode changes",
  limit: "Limits hit",
  fault: "Faults",
  watchdog: "Watchdog stops",
  estop: "Emergency stops",
  impedance: "Stiffness or damping changes",
  hold: "Holds",
  resume: "Resumes",
  stop: "Stops",
  game_score: "Game updates",
  note: "Notes",
};

const $ = (id) => document.getElementById(id);

function fail(message) {
  const box = $("page-error");
  box.textContent = message;
  box.hidden = false;
}

// ---- summary ---------------------------------------------------------------------------------
const capitalised = (text) => text.charAt(0).toUpperCase() + text.slice(1);

function fact(term, ...value) {
  return [el("dt", {}, term), el("dd", {}, ...value)];
}

function renderSummary(session, patient) {
  const sum = session.summary || {};
  const name = patient ? patient.display_name : `Patient ${session.patient_id}`;
  const when = fmt.date(session.started_at);
  $("crumb-patient").textContent = name;
  $("crumb-patient").href = `/app/patients/${session.patient_id}`;
  $("crumb-session").textContent = `Session of ${when}`;
  $("title").textContent = `${name}: session of ${when}`;
  document.title = `${name}, session of ${when} · Ankle telerehabilitation`;

  const reps = sum.repetitions_completed ?? "–";
  const prescribed = sum.repetitions_prescribed ?? "–";
  const game = sum.game;
  $("facts").replaceChildren(
    ...fact("Date", when),
    ...fact("Duration", fmt.duration(sum.elapsed_s), el("span", { class: "muted" }, ` (exercising ${fmt.duration(sum.duration_s)})`)),
    ...fact("Ended", endReasonBadge(session.end_reason), ...(sum.end_text ? [" ", el("span", { id: "end-text" }, sum.end_text)] : [])),
    ...fact("Repetitions", `${reps} of ${prescribed} prescribed`),
    ...fact("Sets completed", sum.sets_completed ?? "–"),
    ...fact(
      "Samples",
      sum.samples ?? "–",
      ...(sum.telemetry_gaps > 0
        ? [" ", el("span", { id: "gaps", class: "data-missing" }, `(${sum.telemetry_gaps} gap${sum.telemetry_gaps === 1 ? "" : "s"} in the telemetry, ${fmt.duration(sum.telemetry_missing_s)} missing: the numbers leave that time out)`)]
        : []),
    ),
    ...(game
      ? fact(
          "Game score",
          `${game.score} of ${game.gates} gates (${game.missed} missed, ${game.games} game${game.games === 1 ? "" : "s"})`,
        )
      : []),
  );

  const axes = Object.entries(sum.axes || {});
  $("axes").tBodies[0].replaceChildren(
    ...axes.map(([axis, a]) =>
      el(
        "tr",
        {},
        el("th", { scope: "row" }, axis),
        el("td", { class: "num" }, fmt.num(a.rom_deg, 1)),
        el("td", { class: "num" }, `${fmt.num(a.rom_min_deg, 1)} · ${fmt.num(a.rom_max_deg, 1)}`),
        el("td", { class: "num" }, fmt.num(a.peak_torque_nm, 1)),
        el("td", { class: "num" }, fmt.num(a.mean_torque_nm, 1)),
        el("td", { class: "num" }, fmt.num(a.work_j, 1)),
      ),
    ),
  );
  if (!axes.length) {
    $("axes").tBodies[0].replaceChildren(el("tr", {}, el("td", { colspan: 6, class: "muted" }, "No exercise recorded.")));
  }

  renderMetrics($("metrics"), sum, patient);

  const faults = sum.faults || [];
  $("faults").replaceChildren(
    ...(faults.length
      ? faults.map((f) => el("li", {}, el("strong", {}, `${fmt.num(f.at_s, 1)} s · ${f.kind}`), ` (${f.by}): ${f.text}`))
      : [el("li", { class: "muted" }, "None.")]),
  );
  const events = Object.entries(sum.events || {});
  $("events").replaceChildren(
    ...(events.length
      ? events.flatMap(([kind, n]) => fact(EVENT_NAMES[kind] || capitalised(fmt.exercise(kind)), n))
      : fact("Events", "none")),
  );
  $("summary").removeAttribute("aria-busy");
}

// ---- charts (uPlot) --------------------------------------------------------------------------
const charts = [];

function chartWidth(target) {
  return Math.max(300, target.clientWidth || 600);
}

/** Shade the exercise (ACTIVE) and the stops (HOLD, ESTOP, FAULT) behind the lines. */
function shader(modes) {
  return (u) => {
    const { ctx } = u;
    const { top, height } = u.bbox;
    ctx.save();
    for (const m of modes) {
      const fill = m.mode === "ACTIVE" ? EXERCISE_SHADE : STOP_MODES.has(m.mode) ? STOP_SHADE : null;
      if (!fill) continue;
      const x0 = u.valToPos(m.start_s, "x", true);
      const x1 = u.valToPos(m.end_s, "x", true);
      ctx.fillStyle = fill;
      ctx.fillRect(x0, top, Math.max(1, x1 - x0), height);
    }
    ctx.restore();
  };
}

function chart(id, series, data, modes, { axes = [{}], scales = {} } = {}) {
  const target = $(id);
  const u = new uPlot(
    {
      width: chartWidth(target),
      height: 240,
      scales: { x: { time: false }, ...scales },
      cursor: { sync: { key: "session" } },
      axes: [{ label: "time since start, s" }, ...axes],
      series: [{ label: "time, s", value: (_, v) => (v == null ? "–" : v.toFixed(2)) }, ...series],
      hooks: { drawClear: [shader(modes)] },
    },
    data,
    target,
  );
  charts.push([u, target]);
  target.uplot = u; // for tests and the console: the chart behind this element
  return u;
}

/** A uPlot scale range from zero (or below, for negative values) to `factor` × the top. */
const headroom = (factor) => (_, lo, hi) => [Math.min(0, lo ?? 0), Math.max(hi ?? 0, 1e-3) * factor];

const line = (label, stroke, extra = {}) => ({
  label,
  stroke,
  width: 1.5,
  value: (_, v) => (v == null ? "–" : v.toFixed(2)),
  ...extra,
});

function renderCharts(s) {
  const axes = s.axes.length ? s.axes : ["roll", "pitch", "yaw"];
  const t = s.time_s;
  chart(
    "chart-angle",
    axes.flatMap((a) => [line(a, COLOURS[a]), line(`${a} target`, COLOURS[a], { width: 1, dash: [6, 4] })]),
    [t, ...axes.flatMap((a) => [s.pose_deg[a], s.pose_cmd_deg[a]])],
    s.modes,
    { axes: [{ label: "degrees" }] },
  );
  chart(
    "chart-torque",
    axes.map((a) => line(a, COLOURS[a])),
    [t, ...axes.map((a) => s.torque_nm[a])],
    s.modes,
    { axes: [{ label: "N·m" }] },
  );
  chart(
    "chart-pressure",
    [
      ...s.pressures_bar.map((_, j) => {
        const leg = Math.floor(j / 2);
        const cap = j % 2 === 0;
        return line(`leg ${leg + 1} ${cap ? "cap" : "rod"}`, LEG_COLOURS[leg], { width: 1, dash: cap ? undefined : [5, 3] });
      }),
      line("supply", "#5b6673", { width: 1, dash: [2, 3] }),
    ],
    [t, ...s.pressures_bar, s.supply_bar],
    s.modes,
    { axes: [{ label: "bar" }] },
  );
  chart(
    "chart-impedance",
    [
      ...axes.map((a) => line(`${a} stiffness`, COLOURS[a], { scale: "K" })),
      ...axes.map((a) => line(`${a} damping`, COLOURS[a], { scale: "B", width: 2, dash: [6, 4] })),
    ],
    [t, ...axes.map((a) => s.stiffness_nm_per_rad[a]), ...axes.map((a) => s.damping_nms_per_rad[a])],
    s.modes,
    {
      // Each scale from zero, with different headroom: a steady K sits near the top and a
      // steady B near the middle, so the damping line is never drawn under the stiffness line.
      scales: { K: { range: headroom(1.15) }, B: { range: headroom(2.2) } },
      axes: [
        { scale: "K", label: "N·m/rad" },
        { scale: "B", label: "N·m·s/rad", side: 1, grid: { show: false } },
      ],
    },
  );
  const every = s.decimated
    ? `${s.rows} points from ${s.samples} samples: each pair of points is the lowest and highest value of ${fmt.num(s.bucket_s, 2)} s, so no peak is lost.`
    : `All ${s.samples} samples.`;
  $("series-note").textContent = `${every} Shaded blue: exercising; shaded red: held, stopped or faulted. Point at a chart to read its values.`;
}

let resizeTimer = null;
window.addEventListener("resize", () => {
  clearTimeout(resizeTimer);
  resizeTimer = setTimeout(() => {
    for (const [u, target] of charts) u.setSize({ width: chartWidth(target), height: 240 });
  }, 150);
});

// ---- 3D replay -------------------------------------------------------------------------------
async function loadReplay() {
  const button = $("replay-load");
  const status = $("replay-status");
  button.disabled = true;
  status.textContent = "Preparing the replay: the first time takes a few seconds…";
  try {
    const r = await api(`/sessions/${sessionId}/replay.viser`, { raw: true });
    // The viewer reads the recording from this page's blob: URL: no token leaves the page.
    const url = URL.createObjectURL(await r.blob());
    const frame = $("replay");
    frame.addEventListener(
      "load",
      () => {
        status.textContent = "Replay loaded: play, pause, scrub and change speed with the bar at its bottom; drag to turn the view.";
      },
      { once: true },
    );
    frame.src = `/api/v1/replay/viewer?playbackPath=${encodeURIComponent(url)}`;
    frame.hidden = false;
    button.remove(); // the replay stays for the page's life: nothing to load again
  } catch (e) {
    status.textContent = `The replay could not be loaded: ${e.message}`;
    button.disabled = false;
  }
}

async function saveFile(button, path, fallback, label, status) {
  button.disabled = true;
  status.textContent = `Preparing ${label}…`;
  try {
    const filename = await download(path, fallback);
    status.textContent = `${label} saved as ${filename}.`;
  } catch (e) {
    status.textContent = `${label} could not be downloaded: ${e.message}`;
  } finally {
    button.disabled = false;
  }
}

// ---- downloads -------------------------------------------------------------------------------
function renderDownloads() {
  const status = $("download-status");
  $("downloads").replaceChildren(
    ...FORMATS.map(([ext, label, what]) => {
      const button = el("button", { type: "button", class: "secondary", title: what, dataset: { format: ext } }, `Download ${label}`);
      button.addEventListener("click", () =>
        saveFile(button, `/sessions/${sessionId}/download/${ext}`, `session-${sessionId}.${ext}`, label, status),
      );
      return button;
    }),
  );
}

// ---- start -----------------------------------------------------------------------------------
$("replay-load").addEventListener("click", loadReplay);
$("replay-save").addEventListener("click", () =>
  saveFile($("replay-save"), `/sessions/${sessionId}/replay`, `session-${sessionId}-replay.html`, "The replay", $("replay-status")),
);
renderDownloads();

try {
  const session = await api(`/sessions/${sessionId}`);
  const patient = await api(`/patients/${session.patient_id}`).catch(() => null);
  renderSummary(session, patient);
} catch (e) {
  fail(`The session could not be loaded: ${e.message}`);
}
try {
  renderCharts(await api(`/sessions/${sessionId}/series`));
} catch (e) {
  $("series-note").textContent = "";
  fail(`The time series could not be loaded: ${e.message}`);
}
