// The metrics that fit a session's exercise (summary.metrics, from sessions/metrics.py):
// per direction, named for the patient's side through the API's direction table; per
// repetition; isometric holds; balance sway; tracking only where the target moved.

import { el, fmt } from "./api.js";
import { directionLabel } from "./progress.js";

const KIND_TEXT = {
  strength: "Strength: torque and work per direction, and each repetition.",
  flexibility: "Flexibility: the furthest angle reached in each direction, and how closely the foot followed the platform's movement.",
  passive_rom: "Passive range of motion: the furthest angle reached in each direction, and how closely the foot followed the platform.",
  isometric: "Isometric: the torque held and for how long, in each repetition.",
  balance: "Balance: how much the platform swayed while the patient kept it level.",
  rom_assessment: "Range of motion assessment: the active range in each direction, trial by trial.",
};

function table(id, caption, head, rows) {
  return el(
    "div",
    { class: "pt-scroll" },
    el(
      "table",
      { id },
      el("caption", {}, caption),
      el("thead", {}, el("tr", {}, head.map((h, i) => el("th", { scope: "col", class: i ? "num" : "" }, h)))),
      el("tbody", {}, rows.map((r) => el("tr", {}, r.map((c, i) => (i ? el("td", { class: "num" }, c) : el("th", { scope: "row" }, c)))))),
    ),
  );
}

/** Each direction of each axis of `axes` ({pitch: {positive, negative}}): [label, metrics]. */
function directionsOf(axes, directions) {
  return Object.entries(axes).flatMap(([axis, a]) => [
    [directionLabel(directions, axis, 1), a.positive],
    [directionLabel(directions, axis, -1), a.negative],
  ]);
}

const repName = (r) => `Set ${r.set}, repetition ${r.rep}`;

function perKg(v, weight) {
  return weight && v != null ? fmt.num(v / weight, 2) : "–";
}

function directionTable(m, directions, weight, withTorque) {
  const head = ["Direction", "Furthest angle (°)"];
  if (withTorque) head.push("Peak torque (N·m)", ...(weight ? ["Peak torque (N·m/kg)"] : []), "Mean torque (N·m)", "Work (J)");
  const rows = directionsOf(m.axes, directions).map(([label, d]) => [
    label,
    fmt.num(d.peak_angle_deg, 1),
    ...(withTorque ? [fmt.num(d.peak_torque_nm, 1), ...(weight ? [perKg(d.peak_torque_nm, weight)] : []), fmt.num(d.mean_torque_nm, 1), fmt.num(d.work_j, 2)] : []),
  ]);
  return table("mx-directions", "Per direction, during exercise", head, rows);
}

function repetitionTable(m, directions, weight) {
  const head = ["Repetition", "Direction", "Furthest angle (°)", "Peak torque (N·m)", ...(weight ? ["Peak torque (N·m/kg)"] : []), "Work (J)"];
  const rows = m.repetitions.flatMap((r) =>
    directionsOf(r.axes, directions).map(([label, d]) => [repName(r), label, fmt.num(d.peak_angle_deg, 1), fmt.num(d.peak_torque_nm, 1), ...(weight ? [perKg(d.peak_torque_nm, weight)] : []), fmt.num(d.work_j, 2)]),
  );
  return table("mx-repetitions", "Per repetition", head, rows);
}

function holdTable(m, directions, weight) {
  const head = ["Repetition", "Pushed towards", "Torque held (N·m)", ...(weight ? ["Torque held (N·m/kg)"] : []), "Time held (s)", "Peak torque (N·m)"];
  const rows = m.repetitions.flatMap((r) => {
    const holds = Object.entries(r.holds || {});
    if (!holds.length) return [[repName(r), "no push held", "–", ...(weight ? ["–"] : []), "0", "–"]];
    return holds.map(([axis, h]) => [repName(r), directionLabel(directions, axis, h.sign), fmt.num(h.torque_nm, 1), ...(weight ? [perKg(h.torque_nm, weight)] : []), fmt.num(h.held_s, 1), fmt.num(h.peak_torque_nm, 1)]);
  });
  return table("mx-holds", "Torque held per repetition", head, rows);
}

function trialTable(m, directions) {
  const columns = directionsOf(m.axes, directions).map(([label]) => label);
  const rows = m.repetitions.map((r, i) => [`Trial ${i + 1}`, ...directionsOf(r.axes, directions).map(([, d]) => fmt.num(d.peak_angle_deg, 1))]);
  return table("mx-trials", "Active range per trial (°)", ["Trial", ...columns], rows);
}

function swayTable(sway) {
  const rows = Object.entries(sway.axes).map(([axis, s]) => [axis.charAt(0).toUpperCase() + axis.slice(1), fmt.num(s.rms_deg, 2), fmt.num(s.range_deg, 1)]);
  return el(
    "div",
    {},
    table("mx-sway", "Sway about level", ["Axis", "RMS (°)", "Range (°)"], rows),
    el("p", { class: "small", id: "mx-path" }, `Path of the platform's tilt: ${fmt.num(sway.path_deg, 1)}° in all, ${fmt.num(sway.mean_speed_deg_s, 2)}°/s on average.`),
  );
}

function trackingTable(tracking) {
  const rows = Object.entries(tracking).map(([axis, t]) => [axis.charAt(0).toUpperCase() + axis.slice(1), fmt.num(t.error_rms_deg, 2), fmt.num(t.time_in_target_pct, 0)]);
  return table("mx-tracking", "Following the platform's movement", ["Axis", "Tracking error, RMS (°)", "Time within 2° of the target (%)"], rows);
}

/** Draw `summary.metrics` into `container` for `patient` (its directions and weight). */
export function renderMetrics(container, summary, patient) {
  const m = summary?.metrics;
  if (!m) {
    container.replaceChildren(el("p", { class: "muted" }, "No exercise metrics for this session."));
    return;
  }
  const directions = patient?.directions;
  const weight = patient?.weight_kg;
  const parts = [el("p", { class: "small", id: "mx-kind" }, KIND_TEXT[m.kind] || "Per direction and per repetition.")];
  const tables = [];
  if (m.kind === "strength" || !KIND_TEXT[m.kind]) {
    tables.push(directionTable(m, directions, weight, true), repetitionTable(m, directions, weight));
  } else if (m.kind === "isometric") {
    tables.push(holdTable(m, directions, weight));
  } else if (m.kind === "balance") {
    if (m.sway) tables.push(swayTable(m.sway));
  } else if (m.kind === "rom_assessment") {
    tables.push(trialTable(m, directions), directionTable(m, directions, weight, false));
  } else {
    tables.push(directionTable(m, directions, weight, false));
  }
  if (Object.keys(m.tracking || {}).length) tables.push(trackingTable(m.tracking));
  if (weight) parts.push(el("p", { class: "muted small" }, `Torque per kilogram uses the body weight on record, ${fmt.num(weight, 1)} kg.`));
  container.replaceChildren(...parts, el("div", { class: "mx-tables" }, ...tables));
}
