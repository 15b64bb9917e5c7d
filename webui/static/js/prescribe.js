// Prescribe an exercise from the library, or edit an active prescription (?edit=ID).
// Every bound on the form comes from the API (its schema and GET /exercises/limits: each
// axis's range, the device's stable K–B envelope, directions for the patient's side), and
// every refusal shown is the API's own sentence beside the field it names: a value past a
// published bound is refused here, before submitting, with the sentence the API publishes
// for it; everything else the API answers.

import {
  ApiError,
  CreateKey,
  RAD2DEG,
  api,
  clearErrors,
  currentUser,
  dropDraft,
  el,
  fmt,
  keepDraft,
  numberValue,
  pathId,
  renderHeader,
  requireSignIn,
  showErrors,
  takeDraft,
} from "./api.js";
import { applyBounds, loadSchemas, prop, rangeText } from "./schema.js";

await requireSignIn();
renderHeader();

const $ = (id) => document.getElementById(id);
const form = $("rx");
const axesBox = $("axes");
const patientId = pathId(2);
const editId = Number.parseInt(new URLSearchParams(location.search).get("edit"), 10) || null;

const BODY = "PrescriptionCreate";
const AXIS = "AxisPrescription";
const TOP_NUMBERS = ["sets", "repetitions", "repetition_s", "rest_s", "torque_limit", "force_limit", "sessions_per_week"];

const AXIS_WORDS = { roll: "Roll", pitch: "Pitch", yaw: "Yaw" };
const WAVEFORM_WORDS = {
  hold: "Hold still",
  sine: "Sine, back and forth",
  ramp: "Ramp to an angle",
};
/** Per-axis inputs: spinner step, the waveforms that use it (all if absent), whether the
 * platform must yield for it to mean anything. Labels and units come from the API. */
const AXIS_FIELDS = [
  { key: "stiffness", step: 1, compliant: true },
  { key: "damping", step: 0.1, compliant: true },
  { key: "waveform" },
  { key: "center", step: 0.5, angle: true },
  { key: "amplitude", step: 0.5, waves: ["sine"] },
  { key: "frequency", step: 0.01, waves: ["sine"] },
  { key: "ramp_end", step: 0.5, waves: ["ramp"], angle: true },
  { key: "ramp_rate", step: 0.5, waves: ["ramp"] },
  { key: "rom_low", step: 0.5, optional: true, angle: true },
  { key: "rom_high", step: 0.5, optional: true, angle: true },
];

let schemas;
let limits; // GET /exercises/limits for this patient's side
let library = new Map();
let current = null; // the prescription being edited

// --- reading and writing values ---------------------------------------------------------

function setValue(input, v) {
  input.value = v === null || v === undefined ? "" : String(v);
}

// --- the axes ---------------------------------------------------------------------------

function axisNames() {
  return [...axesBox.querySelectorAll("fieldset[data-axis]")].map((f) => f.dataset.axis);
}

/** A number as the API's sentences write it: 500, 22.9, 0.698. */
function num(v) {
  if (Number.isInteger(v)) return String(v);
  return Math.abs(v) >= 10 ? String(Math.round(v * 10) / 10) : String(Number(v.toPrecision(3)));
}

/** "0 to 500 N·m/rad (0 to 8.73 N·m/°)": a bound's range in its unit, and per degree. */
function rangeHint(b) {
  const sep = b.unit.startsWith("°") || !b.unit ? "" : " ";
  const text = b.min_exclusive
    ? `above ${num(b.min)}, up to ${num(b.max)}${sep}${b.unit}`
    : `${num(b.min)} to ${num(b.max)}${sep}${b.unit}`;
  if (!b.unit.endsWith("/rad")) return text;
  const perDeg = b.unit.replace(/\/rad$/, "/°");
  return `${text} (${num(b.min / RAD2DEG)} to ${num(b.max / RAD2DEG)} ${perDeg})`;
}

/** Where the platform yields, the least damping in each band of K (the device's envelope). */
function envelopeHint(axis) {
  const bands = limits.axes[axis].envelope;
  const parts = bands.map((band, i) => {
    const next = bands[i + 1];
    const k = next ? `K ${num(band.stiffness_from)}–${num(next.stiffness_from)}` : `K ≥ ${num(band.stiffness_from)}`;
    return `B ≥ ${num(band.damping_min)} at ${k}`;
  });
  return `Steady only with ${parts.join(", ")}.`;
}

function axisField(axis, spec, value) {
  const id = `ax-${axis}-${spec.key}`;
  const p = prop(schemas, AXIS, spec.key);
  if (spec.key === "waveform") {
    const select = el(
      "select",
      { id, name: spec.key },
      p.enum.map((w) => el("option", { value: w }, WAVEFORM_WORDS[w] || w)),
    );
    select.value = value ?? p.default;
    select.addEventListener("change", () => showWaveFields(select.closest("fieldset")));
    return el("div", { class: "field rx-wave" }, el("label", { for: id }, p.title), select);
  }
  const b = limits.axes[axis].fields[spec.key];
  const input = el("input", { id, name: spec.key, type: "number", step: spec.step, "aria-describedby": `${id}-range` });
  if (b.min !== null) input.min = String(b.min);
  if (b.max !== null) input.max = String(b.max);
  setValue(input, value ?? (spec.optional ? null : p.default));
  if (spec.optional) input.placeholder = "whole range";
  let help = rangeHint(b);
  if (spec.optional) help += "; blank: the whole range";
  if (spec.key === "damping") help += `. ${envelopeHint(axis)}`;
  const perDegree = spec.compliant ? el("output", { for: id, class: "rx-per-degree" }) : null;
  if (perDegree) {
    const unit = b.unit.replace(/\/rad$/, "/°");
    const show = () => {
      const v = Number(input.value);
      perDegree.textContent = input.value !== "" && Number.isFinite(v) ? `= ${num(v / RAD2DEG)} ${unit}` : "";
    };
    input.addEventListener("input", show);
    show();
  }
  const dataset = { ...(spec.waves ? { waves: spec.waves.join(" ") } : {}), ...(spec.compliant ? { compliant: "" } : {}) };
  return el(
    "div",
    { class: "field", dataset },
    el("label", { for: id }, `${p.title} `, el("span", { class: "unit" }, `(${b.unit})`)),
    el("div", { class: "rx-input" }, input, perDegree),
    el("span", { id: `${id}-range`, class: "muted small rx-range" }, help),
    el("span", { class: "field-error", role: "alert", dataset: { axisKey: spec.key } }),
  );
}

function showWaveFields(fieldset) {
  const wave = fieldset.querySelector('[name="waveform"]').value;
  for (const f of fieldset.querySelectorAll("[data-waves]")) {
    f.hidden = !f.dataset.waves.split(" ").includes(wave);
  }
}

/** Whether the chosen exercise renders K and B: the library says. */
function compliant() {
  return library.get($("exercise").value)?.compliant ?? true;
}

/** K and B only where the platform yields; elsewhere they are not asked for (and sent as 0,
 * the one value the API takes there). */
function showCompliance() {
  const yields = compliant();
  for (const f of axesBox.querySelectorAll("[data-compliant]")) f.hidden = !yields;
  $("compliance-note").hidden = yields;
}

function axisTitle(axis) {
  const d = limits.axes[axis].directions;
  return `${AXIS_WORDS[axis] || axis} (${d.positive.replaceAll("_", " ")} / ${d.negative.replaceAll("_", " ")})`;
}

function axisBlock(a) {
  const d = limits.axes[a.axis].directions;
  const remove = el(
    "button",
    { type: "button", class: "secondary rx-remove", "aria-label": `Remove the ${a.axis} axis` },
    "Remove",
  );
  const fieldset = el(
    "fieldset",
    { class: "rx-axis", dataset: { axis: a.axis }, tabindex: "-1" },
    el("legend", {}, axisTitle(a.axis)),
    el("p", { class: "muted small rx-directions" }, `Angles above 0: ${d.positive_label}. Below 0: ${d.negative_label}.`),
    el("span", { class: "field-error rx-axis-error", role: "alert" }),
    el("div", { class: "rx-fields" }, AXIS_FIELDS.map((spec) => axisField(a.axis, spec, a[spec.key]))),
    remove,
  );
  remove.addEventListener("click", () => {
    fieldset.remove();
    renumberAxes();
    $("add-axis").focus();
  });
  showWaveFields(fieldset);
  return fieldset;
}

/** data-field paths follow the API's error locations, which count axes from 0 in order. */
function renumberAxes() {
  const blocks = [...axesBox.querySelectorAll("fieldset[data-axis]")];
  blocks.forEach((f, i) => {
    f.dataset.field = `axes.${i}`;
    f.querySelector(".rx-axis-error").dataset.errorFor = `axes.${i}`;
    for (const input of f.querySelectorAll("[name]")) input.dataset.field = `axes.${i}.${input.name}`;
    for (const slot of f.querySelectorAll("[data-axis-key]")) slot.dataset.errorFor = `axes.${i}.${slot.dataset.axisKey}`;
  });
  const { minItems, maxItems } = schemas[BODY].properties.axes;
  for (const b of axesBox.querySelectorAll(".rx-remove")) b.disabled = blocks.length <= minItems;
  const unused = prop(schemas, AXIS, "axis").enum.filter((a) => !axisNames().includes(a));
  $("add-axis").replaceChildren(...unused.map((a) => el("option", { value: a }, axisTitle(a))));
  const full = blocks.length >= maxItems || !unused.length;
  $("add-axis").disabled = full;
  $("add-axis-button").disabled = full;
}

function setAxes(axes) {
  axesBox.replaceChildren(...axes.map(axisBlock));
  renumberAxes();
  showCompliance();
}

function addAxis() {
  const axis = $("add-axis").value;
  if (!axis) return;
  const template = library.get($("exercise").value)?.defaults.axes || [];
  // The exercise's own setting for this axis if it has one, else its first axis's K and B.
  const like = template.find((a) => a.axis === axis) || {
    axis,
    stiffness: template[0]?.stiffness,
    damping: template[0]?.damping,
  };
  const block = axisBlock({ ...like, axis });
  axesBox.append(block);
  renumberAxes();
  showCompliance();
  [...block.querySelectorAll("input")].find((i) => !i.closest("[hidden]"))?.focus();
}

function axisBody(fieldset) {
  const wave = fieldset.querySelector('[name="waveform"]').value;
  const yields = compliant();
  const out = { axis: fieldset.dataset.axis, waveform: wave };
  for (const spec of AXIS_FIELDS) {
    if (spec.key === "waveform") continue;
    if (spec.waves && !spec.waves.includes(wave)) continue; // a stale value would still count
    if (spec.compliant && !yields) {
      out[spec.key] = 0; // not rendered in this exercise: the API takes no other value
      continue;
    }
    out[spec.key] = numberValue(fieldset.querySelector(`[name="${spec.key}"]`));
  }
  return out;
}

// --- the whole form ---------------------------------------------------------------------

function fill(body) {
  $("exercise").value = body.exercise;
  describeExercise();
  setValue($("title"), body.title);
  setValue($("instructions"), body.instructions);
  for (const k of TOP_NUMBERS) setValue($(k), body[k]);
  setAxes(body.axes);
  updateTotal();
}

function formBody() {
  const body = {
    exercise: $("exercise").value,
    title: $("title").value,
    instructions: $("instructions").value,
    axes: [...axesBox.querySelectorAll("fieldset[data-axis]")].map(axisBody),
  };
  for (const k of TOP_NUMBERS) body[k] = numberValue($(k));
  return body;
}

/** What the therapist has typed, as the inputs hold it (text, not yet numbers), in the shape
 * fill() takes: kept if the sign-in expires before it is saved (api.js keepDraft). */
function draftValues() {
  const raw = (input) => input.value;
  const values = { exercise: $("exercise").value, title: $("title").value, instructions: $("instructions").value };
  for (const k of TOP_NUMBERS) values[k] = raw($(k));
  values.axes = [...axesBox.querySelectorAll("fieldset[data-axis]")].map((f) => {
    const axis = { axis: f.dataset.axis };
    for (const input of f.querySelectorAll("[name]")) axis[input.name] = raw(input);
    return axis;
  });
  return values;
}

/** Put back what was typed before the sign-in expired, and say so. */
function restoreDraft(draft) {
  fill(draft.values);
  const at = new Date(draft.saved).toLocaleTimeString();
  $("draft-note").textContent = `Your sign-in had ended, so nothing was saved. What you had typed (at ${at}) is back in the form: check it, then press ${$("submit").textContent} again.`;
  $("draft-note").hidden = false;
}

function describeExercise() {
  const t = library.get($("exercise").value);
  $("exercise-purpose").textContent = t
    ? `${t.purpose} ${t.compliant ? "The platform yields to the foot (stiffness and damping apply)." : "The platform does not yield: stiffness and damping are not rendered."}`
    : "";
}

function updateTotal() {
  const n = (k) => Number($(k).value);
  const total = n("sets") * n("repetitions") * n("repetition_s") + Math.max(n("sets") - 1, 0) * n("rest_s");
  $("total").textContent = Number.isFinite(total) && total > 0 ? `Exercise time per session: ${fmt.duration(total)}, rests included.` : "";
}

// --- refusing before submitting ------------------------------------------------------

/** The published bounds of a number input: its axis's, or the timeline's and safety's. */
function boundsFor(input) {
  const axis = input.closest("fieldset[data-axis]")?.dataset.axis;
  return axis ? limits.axes[axis].fields[input.name] : limits.fields[input.name];
}

/** Values past a published bound, refused as the API would: with its own sentences. */
function localRefusals() {
  const detail = [];
  for (const input of form.querySelectorAll("input[type=number][data-field]")) {
    if (input.closest("[hidden]") || input.value === "") continue;
    const b = boundsFor(input);
    const v = Number(input.value);
    if (!b || !Number.isFinite(v)) continue;
    let msg = null;
    if (b.min !== null && (b.min_exclusive ? v <= b.min : v < b.min)) msg = b.below;
    else if (b.max !== null && v > b.max) msg = b.above;
    if (msg) {
      const loc = input.dataset.field.split(".").map((p) => (/^\d+$/.test(p) ? Number(p) : p));
      detail.push({ type: "out_of_range", loc: ["body", ...loc], msg });
    }
  }
  return detail;
}

function sideNote(side) {
  if (side === "left" || side === "right") return `Directions are named for the patient's ${side} foot.`;
  if (side === "both") return "Both sides are affected: roll and yaw are named as the platform moves.";
  return "The patient's affected side is not recorded: roll and yaw are named as the platform moves. Record it on the patient's page to name inversion and eversion.";
}

// --- loading and saving -----------------------------------------------------------------

const createKey = new CreateKey();

async function submit(ev) {
  ev.preventDefault();
  const button = $("submit");
  button.disabled = true;
  clearErrors(form);
  const refused = localRefusals();
  if (refused.length) {
    showErrors(form, new ApiError(422, refused));
    button.disabled = false;
    return;
  }
  try {
    const saved = editId
      ? await api(`/prescriptions/${editId}`, { method: "PATCH", body: formBody() })
      : await api(`/patients/${patientId}/prescriptions`, {
          method: "POST",
          body: formBody(),
          once: createKey,
        });
    dropDraft();
    location.href = `/app/patients/${patientId}?saved=${saved.id}`;
  } catch (e) {
    showErrors(form, e);
    button.disabled = false;
  }
}

function boundTopFields() {
  for (const k of ["title", "instructions", ...TOP_NUMBERS]) {
    const p = prop(schemas, BODY, k);
    applyBounds($(k), p);
    const range = $(`${k}-range`);
    if (range) range.textContent = limits.fields[k] ? rangeHint(limits.fields[k]) : rangeText(p);
  }
}

async function main() {
  if (patientId === null) throw new Error("no patient in this address");
  const [s, exercises, patient, rx] = await Promise.all([
    loadSchemas(),
    api("/exercises"),
    api(`/patients/${patientId}`),
    editId ? api(`/prescriptions/${editId}`) : null,
  ]);
  schemas = s;
  limits = await api(`/exercises/limits${patient.affected_side ? `?side=${patient.affected_side}` : ""}`);
  $("side-note").textContent = sideNote(patient.affected_side);
  library = new Map(exercises.map((x) => [x.kind, x]));
  if (rx && rx.patient_id !== patientId) throw new Error("this prescription belongs to another patient");
  current = rx;

  const back = `/app/patients/${patientId}`;
  $("crumb-patient").textContent = patient.display_name;
  $("crumb-patient").href = back;
  $("cancel").href = back;
  const title = current
    ? `Edit “${current.body.title || current.body.exercise}” for ${patient.display_name}`
    : `Prescribe an exercise for ${patient.display_name}`;
  $("heading").textContent = title;
  $("crumb-here").textContent = current ? "Edit prescription" : "Prescribe";
  document.title = `${title} · Ankle telerehabilitation`;

  $("exercise").replaceChildren(...exercises.map((x) => el("option", { value: x.kind }, x.name)));
  boundTopFields();
  if (current) {
    fill(current.body);
    $("submit").textContent = `Save as version ${current.version + 1}`;
    if (current.status !== "active") {
      $("status-note").textContent = `This prescription is ${current.status}: it can no longer be changed. Prescribe a new one instead.`;
      $("status-note").hidden = false;
      $("submit").disabled = true;
    } else {
      $("status-note").textContent = `Version ${current.version}. Saving replaces its settings; the patient's station fetches the new version.`;
      $("status-note").hidden = false;
    }
  } else {
    fill(exercises[0].defaults);
  }
  if (currentUser()?.role !== "therapist") {
    $("submit").disabled = true; // the API lets only the patient's own therapist prescribe
  }

  $("exercise").addEventListener("change", () => {
    clearErrors(form);
    fill(library.get($("exercise").value).defaults);
  });
  $("add-axis-button").addEventListener("click", addAxis);
  for (const k of ["sets", "repetitions", "repetition_s", "rest_s"]) $(k).addEventListener("input", updateTotal);
  form.addEventListener("submit", submit);
  const draft = takeDraft();
  if (draft) restoreDraft(draft);
  keepDraft(draftValues);
  form.hidden = false;
  $("exercise").focus();
}

main().catch((e) => {
  $("load-error").textContent = `The form could not be loaded: ${e.message}`;
  $("load-error").hidden = false;
});
