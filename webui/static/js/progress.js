// A patient's progress from GET /patients/{id}/progress, drawn with Chart.js: per exercise
// type, one line per direction (named for the patient's side by the API's direction table),
// the baseline of the first ROM assessment, changes flagged only beyond the MDC95; and
// adherence per prescription per prescribed week. Each chart has a caption in words and a
// data table behind it.

import { api, el, fmt } from "./api.js";

// Colour, marker and dash all differ, so the lines stay apart without colour vision.
const STYLES = [
  { color: "#b3261e", point: "rect", dash: [] },
  { color: "#1f5fbf", point: "circle", dash: [6, 4] },
  { color: "#1d7a3a", point: "triangle", dash: [2, 3] },
  { color: "#8e44ad", point: "rectRot", dash: [10, 3] },
  { color: "#d08400", point: "crossRot", dash: [4, 2, 1, 2] },
  { color: "#17324f", point: "star", dash: [1, 2] },
];
const QUANTITY = {
  peak_angle: { title: "Furthest angle per direction", unit: "°", axis: "degrees", digits: 1 },
  peak_torque: { title: "Peak torque per direction", unit: "N·m", axis: "N·m", digits: 1 },
  torque_held: { title: "Torque held per direction", unit: "N·m", axis: "N·m", digits: 1 },
  sway_rms: { title: "Sway (RMS about level; lower is steadier)", unit: "°", axis: "degrees", digits: 2 },
};
const TORQUE = new Set(["peak_torque", "torque_held"]);

const cap = (s) => s.charAt(0).toUpperCase() + s.slice(1);
const withUnit = (v, unit, digits) => `${fmt.num(v, digits)}${unit === "°" ? "°" : ` ${unit}`}`;
const signed = (v, unit, digits) => `${v > 0 ? "+" : ""}${withUnit(v, unit, digits)}`;

/** The label of one measure's direction, from the API's direction table. */
export function directionLabel(directions, axis, sign) {
  if (sign === 0) return cap(axis);
  const d = directions?.[axis];
  if (!d) return `${cap(axis)} ${sign > 0 ? "positive" : "negative"}`;
  return sign > 0 ? d.positive_label : d.negative_label;
}

function sessionLabel(iso) {
  return new Date(iso).toLocaleString(undefined, { day: "numeric", month: "short", hour: "2-digit", minute: "2-digit" });
}

function dataTable(caption, head, rows) {
  return el(
    "details",
    { class: "pt-data" },
    el("summary", {}, "Show the numbers"),
    el(
      "div",
      { class: "pt-scroll" },
      el(
        "table",
        {},
        el("caption", { class: "sr-only" }, caption),
        el("thead", {}, el("tr", {}, head.map((h, i) => el("th", { scope: "col", class: i ? "num" : "" }, h)))),
        el(
          "tbody",
          {},
          rows.map((r) => el("tr", {}, r.map((c, i) => (i ? el("td", { class: "num" }, c) : el("th", { scope: "row" }, c))))),
        ),
      ),
    ),
  );
}

function figure(id, title, summary, table) {
  const canvas = el("canvas", { id: `${id}-canvas`, role: "img", "aria-label": `${title}. ${summary}` });
  const fig = el(
    "figure",
    { class: "card pt-figure", id },
    el("figcaption", {}, el("strong", {}, title), el("span", { class: "muted small pt-summary" }, summary)),
    el("div", { class: "chart-box" }, canvas),
    table,
  );
  return { fig, canvas };
}

function emptyFigure(id, title, text) {
  return el(
    "figure",
    { class: "card pt-figure", id },
    el("figcaption", {}, el("strong", {}, title)),
    el("p", { class: "muted pt-empty", dataset: { empty: "" } }, text),
  );
}

function options(yTitle, beginAtZero = true) {
  return {
    responsive: true,
    maintainAspectRatio: false,
    animation: false,
    interaction: { mode: "index", intersect: false },
    scales: {
      // offset: a lone first session sits mid-chart, not on the axis line
      x: { offset: true, title: { display: true, text: "Session" } },
      // A short title: a long one is clipped on a chart this high.
      y: { beginAtZero, title: { display: true, text: yTitle } },
    },
    plugins: {
      legend: {
        position: "bottom",
        // A baseline is its direction's colour, dotted, and said in the caption: a legend
        // entry each would take the plot's height on a narrow chart.
        labels: { usePointStyle: true, filter: (item, data) => !data.datasets[item.datasetIndex].baseline },
      },
    },
  };
}

function mdcFor(progress, m) {
  return progress.mdc.find((d) => d.axis === m.axis && d.sign === m.sign);
}

/** What a measure did over the sessions, in words, with the baseline and MDC95 verdict. */
function measureWords(progress, m, label) {
  const q = QUANTITY[m.quantity];
  const pts = m.points;
  const last = pts[pts.length - 1];
  let text = pts.length === 1 ? `${label} ${withUnit(last.value, q.unit, q.digits)}` : `${label} from ${withUnit(pts[0].value, q.unit, q.digits)} to ${withUnit(last.value, q.unit, q.digits)}`;
  if (m.baseline != null && last.change != null) {
    const mdc = mdcFor(progress, m);
    const verdict =
      last.real_change === true
        ? `a real change (beyond MDC95 ${withUnit(mdc.mdc95_deg, "°", 1)})`
        : last.real_change === false
          ? `within MDC95 ${withUnit(mdc.mdc95_deg, "°", 1)}: not a detectable change`
          : `not judged, MDC95 ${mdc ? mdc.text : "not measured"}`;
    text += `, ${signed(last.change, q.unit, q.digits)} from the baseline ${withUnit(m.baseline, q.unit, q.digits)}, ${verdict}`;
  }
  return text;
}

function exerciseChart(progress, ex, name) {
  const quantity = ex.measures[0].quantity;
  const q = QUANTITY[quantity];
  const id = `chart-${ex.exercise}`;
  const title = `${name}: ${q.title.charAt(0).toLowerCase()}${q.title.slice(1)}`;
  // One x position per session of this type, oldest first.
  const sessions = new Map();
  for (const m of ex.measures) for (const p of m.points) sessions.set(p.session_id, p.at);
  const ids = [...sessions.keys()].sort((a, b) => new Date(sessions.get(a)) - new Date(sessions.get(b)));
  const labels = ids.map((id) => sessionLabel(sessions.get(id)));
  const weight = progress.weight_kg;
  const perKg = TORQUE.has(quantity) && weight;

  const datasets = [];
  const head = ["Session"];
  const columns = [];
  ex.measures.forEach((m, k) => {
    const style = STYLES[k % STYLES.length];
    const label = directionLabel(progress.directions, m.axis, m.sign);
    const at = new Map(m.points.map((p) => [p.session_id, p]));
    const points = ids.map((id) => at.get(id) ?? null);
    datasets.push({
      label,
      data: points.map((p) => p?.value ?? null),
      borderColor: style.color,
      backgroundColor: style.color,
      borderDash: style.dash,
      pointStyle: style.point,
      // A change beyond the MDC95 is drawn larger, and listed as such in the table.
      pointRadius: points.map((p) => (p?.real_change ? 8 : 4)),
      spanGaps: true,
    });
    if (m.baseline != null) {
      datasets.push({
        baseline: true,
        label: `${label}: baseline`,
        data: ids.map(() => m.baseline),
        borderColor: style.color,
        backgroundColor: "transparent",
        borderDash: [2, 4],
        borderWidth: 1,
        pointRadius: 0,
        pointStyle: "line",
      });
    }
    head.push(`${label}, ${q.unit}`);
    columns.push((i) => {
      const p = points[i];
      if (!p) return "–";
      let cell = fmt.num(p.value, q.digits);
      if (perKg) cell += ` (${fmt.num(p.value / weight, 2)} N·m/kg)`;
      if (p.trials > 1) cell += ` · ${p.trials} trials`;
      if (p.change != null) cell += ` · ${signed(p.change, q.unit, q.digits)}${p.real_change ? " real change" : ""}`;
      return cell;
    });
  });
  const words = ex.measures.map((m) => measureWords(progress, m, directionLabel(progress.directions, m.axis, m.sign)));
  const dotted = ex.measures.some((m) => m.baseline != null) ? " Dotted lines: the baselines." : "";
  const summary = `${ex.sessions} session${ex.sessions === 1 ? "" : "s"}, oldest first. ${words.join("; ")}.${dotted}`;
  const table = dataTable(title, head, ids.map((_, i) => [labels[i], ...columns.map((c) => c(i))]));
  const { fig, canvas } = figure(id, title, summary, table);
  return { fig, canvas, config: { type: "line", data: { labels, datasets }, options: options(q.axis) } };
}

function weekLabel(w) {
  return `Week ${w.week} (${new Date(w.start).toLocaleDateString(undefined, { day: "numeric", month: "short" })})`;
}

/** In words: this week, and the weeks that are over, never above what was prescribed. */
export function adherenceWords(a) {
  const now = a.weeks.find((w) => w.in_progress);
  const parts = [];
  if (now) parts.push(`This week ${now.completed} of ${now.prescribed} prescribed sessions completed${now.extra ? `, ${now.extra} extra` : ""}${now.ended_early ? `, ${now.ended_early} ended early` : ""}.`);
  const over = a.weeks.filter((w) => !w.in_progress).length;
  if (over) {
    const pct = a.percent == null ? "" : ` (${Math.round(a.percent)} %)`;
    parts.push(
      `Over ${over} week${over === 1 ? "" : "s"} that ended: ${a.completed} of ${a.prescribed}${pct}` +
        `${a.extra ? `, ${a.extra} extra` : ""}${a.ended_early ? `, ${a.ended_early} ended early` : ""}, ${a.missed} missed.`,
    );
  }
  return parts.join(" ") || "No prescribed week in this range.";
}

function adherenceChart(a, name) {
  const id = `chart-adherence-${a.prescription_id}`;
  const title = `Adherence: ${a.title || name}, ${a.sessions_per_week} a week`;
  const labels = a.weeks.map(weekLabel);
  const summary = adherenceWords(a);
  const table = dataTable(
    title,
    ["Week", "Prescribed", "Completed", "Extra", "Ended early", "Missed"],
    a.weeks.map((w, i) => [labels[i] + (w.in_progress ? " (this week)" : ""), w.prescribed, w.completed, w.extra, w.ended_early, w.missed]),
  );
  const { fig, canvas } = figure(id, title, summary, table);
  fig.classList.add("pt-adherence");
  const bar = (label, key, color, stack = "done") => ({ label, data: a.weeks.map((w) => w[key]), backgroundColor: color, pointStyle: "rect", maxBarThickness: 48, stack });
  const config = {
    type: "bar",
    data: {
      labels,
      datasets: [
        bar("Completed", "completed", "#1d7a3a"),
        bar("Extra", "extra", "#7fb88f"),
        bar("Ended early", "ended_early", "#d08400"),
        bar("Missed", "missed", "#c9ced6"),
        {
          // A target mark across each week's bar: what was prescribed.
          type: "line",
          label: "Prescribed",
          data: a.weeks.map((w) => w.prescribed),
          borderColor: "#17324f",
          backgroundColor: "#17324f",
          showLine: false,
          pointStyle: "line",
          pointRadius: 24,
          pointHoverRadius: 24,
          pointBorderWidth: 3,
          stack: "prescribed",
        },
      ],
    },
    options: {
      responsive: true,
      maintainAspectRatio: false,
      animation: false,
      scales: {
        x: { stacked: true },
        y: { stacked: true, beginAtZero: true, ticks: { precision: 0 }, title: { display: true, text: "Sessions" } },
      },
      plugins: { legend: { position: "bottom", labels: { usePointStyle: true } } },
    },
  };
  return { fig, canvas, config };
}

/** The MDC95 per direction in a line of words, with how many trials it rests on. */
export function mdcWords(progress) {
  if (!progress.mdc.length) return "Minimal detectable change: no ROM assessment yet.";
  return (
    "Minimal detectable change (MDC95) from this device's repeated assessment trials: " +
    progress.mdc.map((d) => `${directionLabel(progress.directions, d.axis, d.sign)} ${d.mdc95_deg == null ? d.text : `${withUnit(d.mdc95_deg, "°", 1)} (${d.trials} trials in ${d.assessments} assessments)`}`).join("; ") +
    "."
  );
}

/** The query for the progress API from the filter form; an empty field is left out. The
 * days typed are the therapist's own, so the page names their time zone, as the report form
 * does: else the server counts UTC days, and an evening session falls on the next one. */
export function progressQuery(form) {
  const params = new URLSearchParams();
  for (const name of ["since", "until", "kind"]) {
    const v = form?.elements[name]?.value;
    if (v) params.set(name, v);
  }
  const zone = Intl.DateTimeFormat().resolvedOptions().timeZone;
  if (zone && (params.has("since") || params.has("until"))) params.set("tz", zone);
  const q = params.toString();
  return q ? `?${q}` : "";
}

/**
 * Fetch the patient's progress (with the filter form's range and type) and draw it in
 * `container`; `name(kind)` is the exercise's name. Errors go to `errorBox`.
 */
export async function renderProgress(container, patientId, { form = null, name = cap, errorBox = null, note = null } = {}) {
  let progress;
  try {
    progress = await api(`/patients/${patientId}/progress${progressQuery(form)}`);
  } catch (e) {
    if (errorBox) {
      errorBox.textContent = `The progress could not be loaded: ${e.message}`;
      errorBox.hidden = false;
    }
    return null;
  }
  if (errorBox) errorBox.hidden = true;
  for (const c of container.querySelectorAll("canvas")) globalThis.Chart?.getChart(c)?.destroy();
  if (note) note.textContent = mdcWords(progress);

  const parts = progress.exercises.filter((ex) => ex.measures.length).map((ex) => exerciseChart(progress, ex, name(ex.exercise)));
  const shown = progress.adherence.filter((a) => a.weeks.length);
  const adherence = shown.map((a) => adherenceChart(a, name(a.exercise)));
  container.replaceChildren(
    ...(parts.length ? parts.map((p) => p.fig) : [emptyFigure("chart-progress", "Progress per exercise", "No recorded session in this range: the charts appear after the patient's first session.")]),
    ...(adherence.length ? adherence.map((p) => p.fig) : [emptyFigure("chart-adherence", "Adherence", "Nothing prescribed in this range.")]),
  );
  const all = [...parts, ...adherence];
  if (!globalThis.Chart) {
    // The numbers are still there in each figure's table.
    for (const p of all) p.canvas.parentElement.replaceWith(el("p", { class: "error" }, "The chart library is not installed on the server; the numbers are below."));
    return progress;
  }
  for (const p of all) new globalThis.Chart(p.canvas, p.config);
  return progress;
}
