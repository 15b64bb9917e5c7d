// A patient's progress over sessions, drawn with Chart.js: range of motion and peak torque
// per axis, and adherence (sessions done per week against what was prescribed). Each chart
// has a caption that says what it shows in words and a data table behind it.

import { el, fmt } from "./api.js";
import { AXES } from "./axes.js";

export { AXES };
const AXIS_STYLE = {
  // Colour and marker both differ, so the lines stay apart without colour vision.
  roll: { color: "#1f5fbf", point: "circle" },
  pitch: { color: "#b3261e", point: "rect" },
  yaw: { color: "#1d7a3a", point: "triangle" },
};
const MAX_WEEKS = 12;
const DAY_MS = 86_400_000;

const cap = (s) => s.charAt(0).toUpperCase() + s.slice(1);

function sessionLabel(iso) {
  return new Date(iso).toLocaleString(undefined, {
    day: "numeric",
    month: "short",
    hour: "2-digit",
    minute: "2-digit",
  });
}

/** Sessions with a summary, oldest first: the x axis of the per-session charts. */
export function summarized(sessions) {
  return sessions
    .filter((s) => s.summary && s.summary.axes)
    .sort((a, b) => new Date(a.started_at) - new Date(b.started_at));
}

/** {labels, axes: {pitch: [values…]}} for one AxisSummary key, axes in roll-pitch-yaw order. */
export function perAxis(sessions, key) {
  const present = AXES.filter((a) => sessions.some((s) => s.summary.axes[a]?.[key] != null));
  return {
    labels: sessions.map((s) => sessionLabel(s.started_at)),
    axes: Object.fromEntries(
      present.map((a) => [a, sessions.map((s) => s.summary.axes[a]?.[key] ?? null)]),
    ),
  };
}

function mondayOf(date) {
  const d = new Date(date);
  d.setHours(0, 0, 0, 0);
  d.setDate(d.getDate() - ((d.getDay() + 6) % 7));
  return d;
}

/**
 * Weeks (Monday to Sunday, local time) from the first prescription or session to this one,
 * at most MAX_WEEKS: sessions completed, sessions ended early, and the sessions per week
 * the prescriptions active in that week asked for.
 */
export function adherence(sessions, prescriptions, now = new Date()) {
  const starts = [
    ...prescriptions.map((p) => new Date(p.created_at)),
    ...sessions.map((s) => new Date(s.started_at)),
  ];
  if (!starts.length) return [];
  const last = mondayOf(now);
  let first = mondayOf(new Date(Math.min(...starts)));
  const earliest = new Date(last.getTime() - (MAX_WEEKS - 1) * 7 * DAY_MS);
  if (first < earliest) first = mondayOf(earliest);
  const weeks = [];
  for (let w = new Date(first); w <= last; w = new Date(w.getTime() + 7 * DAY_MS)) {
    const end = new Date(w.getTime() + 7 * DAY_MS);
    const inWeek = sessions.filter((s) => {
      const t = new Date(s.started_at);
      return t >= w && t < end;
    });
    const prescribed = prescriptions
      .filter((p) => {
        const created = new Date(p.created_at);
        // A withdrawn or finished prescription counts up to its last change of status.
        const ended = p.status === "active" ? null : new Date(p.updated_at);
        return created < end && (ended === null || ended >= w);
      })
      .reduce((sum, p) => sum + p.body.sessions_per_week, 0);
    weeks.push({
      start: w,
      completed: inWeek.filter((s) => s.end_reason === "completed").length,
      early: inWeek.filter((s) => s.end_reason !== "completed").length,
      prescribed,
    });
  }
  return weeks;
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
          rows.map((r) =>
            el("tr", {}, r.map((c, i) => (i ? el("td", { class: "num" }, c) : el("th", { scope: "row" }, c)))),
          ),
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

function trendWords(series, unit, digits) {
  return Object.entries(series.axes)
    .map(([axis, values]) => {
      const known = values.filter((v) => v !== null);
      if (!known.length) return `${cap(axis)}: no value`;
      const a = fmt.num(known[0], digits);
      const b = fmt.num(known[known.length - 1], digits);
      const u = unit === "°" ? unit : ` ${unit}`;
      return known.length === 1 ? `${cap(axis)} ${a}${u}` : `${cap(axis)} from ${a}${u} to ${b}${u}`;
    })
    .join("; ");
}

function lineOptions(yTitle) {
  return {
    responsive: true,
    maintainAspectRatio: false,
    animation: false,
    interaction: { mode: "index", intersect: false },
    scales: {
      // offset: a lone first session sits mid-chart, not on the axis line
      x: { offset: true, title: { display: true, text: "Session" } },
      y: { beginAtZero: true, title: { display: true, text: yTitle } },
    },
    plugins: { legend: { position: "bottom", labels: { usePointStyle: true } } },
  };
}

function axisChart(id, title, yTitle, unit, digits, series, count) {
  const summary = `${count} session${count === 1 ? "" : "s"}, oldest first. ${trendWords(series, unit, digits)}.`;
  const axes = Object.keys(series.axes);
  const table = dataTable(
    title,
    ["Session", ...axes.map((a) => `${cap(a)} (${unit})`)],
    series.labels.map((label, i) => [label, ...axes.map((a) => fmt.num(series.axes[a][i], digits))]),
  );
  const { fig, canvas } = figure(id, title, summary, table);
  const config = {
    type: "line",
    data: {
      labels: series.labels,
      datasets: axes.map((a) => ({
        label: `${cap(a)} (${unit})`,
        data: series.axes[a],
        borderColor: AXIS_STYLE[a].color,
        backgroundColor: AXIS_STYLE[a].color,
        pointStyle: AXIS_STYLE[a].point,
        pointRadius: 4,
        spanGaps: true,
      })),
    },
    options: lineOptions(yTitle),
  };
  return { fig, canvas, config };
}

function adherenceChart(weeks) {
  const title = "Adherence: sessions per week";
  const labels = weeks.map((w) => `Week of ${w.start.toLocaleDateString(undefined, { day: "numeric", month: "short" })}`);
  const done = weeks.reduce((n, w) => n + w.completed, 0);
  const asked = weeks.reduce((n, w) => n + w.prescribed, 0);
  const now = weeks[weeks.length - 1];
  const pct = asked ? ` (${Math.round((100 * done) / asked)} %)` : "";
  const summary =
    `This week ${now.completed} of ${now.prescribed} prescribed sessions completed` +
    (now.early ? `, ${now.early} ended early` : "") +
    `. Over ${weeks.length} week${weeks.length === 1 ? "" : "s"}: ${done} of ${asked}${pct}.`;
  const table = dataTable(
    title,
    ["Week", "Completed", "Ended early", "Prescribed"],
    weeks.map((w, i) => [labels[i], w.completed, w.early, w.prescribed]),
  );
  const { fig, canvas } = figure("chart-adherence", title, summary, table);
  const config = {
    type: "bar",
    data: {
      labels,
      datasets: [
        { label: "Completed", data: weeks.map((w) => w.completed), backgroundColor: "#1d7a3a", pointStyle: "rect", maxBarThickness: 48, stack: "done" },
        { label: "Ended early", data: weeks.map((w) => w.early), backgroundColor: "#d08400", pointStyle: "rect", maxBarThickness: 48, stack: "done" },
        {
          // A target mark across each week's bar: bar below the mark is a shortfall.
          type: "line",
          label: "Prescribed",
          data: weeks.map((w) => w.prescribed),
          borderColor: "#17324f",
          backgroundColor: "#17324f",
          showLine: false,
          pointStyle: "line",
          pointRadius: 28,
          pointHoverRadius: 28,
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

/** Replace the charts in `container` with ones for these sessions and prescriptions. */
export function renderProgress(container, sessions, prescriptions) {
  for (const c of container.querySelectorAll("canvas")) globalThis.Chart?.getChart(c)?.destroy();
  const done = summarized(sessions);
  const parts = [];
  const none = "No recorded session yet: this chart appears after the patient's first session.";
  if (done.length) {
    parts.push(axisChart("chart-rom", "Range of motion per axis", "Range of motion (degrees)", "°", 1, perAxis(done, "rom_deg"), done.length));
    parts.push(axisChart("chart-torque", "Peak torque per axis", "Peak torque (N·m)", "N·m", 1, perAxis(done, "peak_torque_nm"), done.length));
  }
  const weeks = adherence(sessions, prescriptions);
  if (weeks.length) parts.push(adherenceChart(weeks));

  container.replaceChildren(
    ...(done.length ? [] : [emptyFigure("chart-rom", "Range of motion per axis", none), emptyFigure("chart-torque", "Peak torque per axis", none)]),
    ...parts.map((p) => p.fig),
    ...(weeks.length ? [] : [emptyFigure("chart-adherence", "Adherence: sessions per week", "Nothing prescribed yet.")]),
  );
  if (!globalThis.Chart) {
    // The numbers are still there in each figure's table.
    for (const p of parts) {
      p.canvas.parentElement.replaceWith(el("p", { class: "error" }, "The chart library is not installed on the server; the numbers are below."));
    }
    return;
  }
  for (const p of parts) new globalThis.Chart(p.canvas, p.config);
}
