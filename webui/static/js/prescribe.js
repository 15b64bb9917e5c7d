// Prescribe an exercise from the library, or edit an active prescription (?edit=ID).
// Every bound on the form comes from the API's published schema, and every refusal shown is
// the API's own message beside the field it names.

import { ApiError, api, clearErrors, currentUser, el, fmt, pathId, renderHeader, requireSignIn, showErrors } from "./api.js";
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

const AXIS_WORDS = {
  roll: "Roll (inversion / eversion)",
  pitch: "Pitch (plantar / dorsiflexion)",
  yaw: "Yaw (ab- / adduction)",
};
const WAVEFORM_WORDS = {
  hold: "Hold still",
  sine: "Sine, back and forth",
  ramp: "Ramp to an angle",
};
/** Per-axis inputs: label, unit, spinner step, and the waveforms that use it (all if absent). */
const AXIS_FIELDS = [
  { key: "stiffness", label: "Stiffness K", unit: "N·m/rad", step: 1 },
  { key: "damping", label: "Damping B", unit: "N·m·s/rad", step: 0.1 },
  { key: "waveform" },
  { key: "center", label: "Center", unit: "degrees", step: 0.5 },
  { key: "amplitude", label: "Amplitude", unit: "degrees", step: 0.5, waves: ["sine"] },
  { key: "frequency", label: "Frequency", unit: "Hz", step: 0.01, waves: ["sine"] },
  { key: "ramp_end", label: "Ramp end", unit: "degrees", step: 0.5, waves: ["ramp"] },
  { key: "ramp_rate", label: "Ramp rate", unit: "degrees/s", step: 0.5, waves: ["ramp"] },
  { key: "rom_low", label: "Lowest angle", unit: "degrees", step: 0.5, optional: true },
  { key: "rom_high", label: "Highest angle", unit: "degrees", step: 0.5, optional: true },
];

let schemas;
let library = new Map();
let current = null; // the prescription being edited

// --- reading and writing values ---------------------------------------------------------

/** A number input's value for the API: a number, null when empty, or the typed text when
 * the browser could not read it, so that the API explains what is wrong with it. */
function numberValue(input) {
  if (input.value === "") return input.validity.badInput ? "not a number" : null;
  return Number(input.value);
}

function setValue(input, v) {
  input.value = v === null || v === undefined ? "" : String(v);
}

// --- the axes ---------------------------------------------------------------------------

function axisNames() {
  return [...axesBox.querySelectorAll("fieldset[data-axis]")].map((f) => f.dataset.axis);
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
    return el("div", { class: "field rx-wave" }, el("label", { for: id }, "Target motion"), select);
  }
  const input = el("input", { id, name: spec.key, type: "number", step: spec.step, "aria-describedby": `${id}-range` });
  applyBounds(input, p);
  setValue(input, value ?? (spec.optional ? null : p.default));
  if (spec.optional) input.placeholder = "allowed";
  const help = spec.optional ? `${rangeText(p)}; blank: the allowed range` : rangeText(p);
  return el(
    "div",
    { class: "field", dataset: spec.waves ? { waves: spec.waves.join(" ") } : {} },
    el("label", { for: id }, `${spec.label} `, el("span", { class: "unit" }, `(${spec.unit})`)),
    input,
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

function axisBlock(a) {
  const remove = el(
    "button",
    { type: "button", class: "secondary rx-remove", "aria-label": `Remove the ${a.axis} axis` },
    "Remove",
  );
  const fieldset = el(
    "fieldset",
    { class: "rx-axis", dataset: { axis: a.axis }, tabindex: "-1" },
    el("legend", {}, AXIS_WORDS[a.axis] || a.axis),
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
  $("add-axis").replaceChildren(...unused.map((a) => el("option", { value: a }, AXIS_WORDS[a] || a)));
  const full = blocks.length >= maxItems || !unused.length;
  $("add-axis").disabled = full;
  $("add-axis-button").disabled = full;
}

function setAxes(axes) {
  axesBox.replaceChildren(...axes.map(axisBlock));
  renumberAxes();
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
  block.querySelector("input").focus();
}

function axisBody(fieldset) {
  const wave = fieldset.querySelector('[name="waveform"]').value;
  const out = { axis: fieldset.dataset.axis, waveform: wave };
  for (const spec of AXIS_FIELDS) {
    if (spec.key === "waveform") continue;
    if (spec.waves && !spec.waves.includes(wave)) continue; // a stale value would still count
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

// --- the API's refusals, beside the field they are about --------------------------------

/** Which input of an axis a model-level message from AxisPrescription is about. */
function axisKeyFor(msg, fieldset) {
  const wave = fieldset?.querySelector('[name="waveform"]').value;
  const blank = (k) => fieldset?.querySelector(`[name="${k}"]`).value === "";
  if (/^rom_low .* is below/.test(msg)) return "rom_low";
  if (/^rom_high .* is above/.test(msg)) return "rom_high";
  if (/^rom_low .* must be below rom_high/.test(msg)) return blank("rom_low") ? "rom_high" : "rom_low";
  if (/needs a frequency/.test(msg)) return "frequency";
  if (/needs a ramp_rate/.test(msg)) return "ramp_rate";
  if (/target spans/.test(msg)) return { sine: "amplitude", ramp: "ramp_end" }[wave] || "center";
  if (/moves at up to/.test(msg)) return { sine: "frequency", ramp: "ramp_rate" }[wave] || null;
  return null;
}

function placed(error) {
  if (!(error instanceof ApiError) || !Array.isArray(error.detail)) return error;
  const detail = error.detail.map((d) => {
    const loc = d.loc || [];
    if (loc.length === 3 && loc[0] === "body" && loc[1] === "axes" && Number.isInteger(loc[2])) {
      const fieldset = axesBox.querySelector(`[data-field="axes.${loc[2]}"]`);
      const key = axisKeyFor(d.msg.replace(/^Value error, /, ""), fieldset);
      if (key) return { ...d, loc: [...loc, key] };
    }
    return d;
  });
  return new ApiError(error.status, detail);
}

// --- loading and saving -----------------------------------------------------------------

async function submit(ev) {
  ev.preventDefault();
  const button = $("submit");
  button.disabled = true;
  clearErrors(form);
  try {
    const saved = editId
      ? await api(`/prescriptions/${editId}`, { method: "PATCH", body: formBody() })
      : await api(`/patients/${patientId}/prescriptions`, { method: "POST", body: formBody() });
    location.href = `/app/patients/${patientId}?saved=${saved.id}`;
  } catch (e) {
    showErrors(form, placed(e));
    button.disabled = false;
  }
}

function boundTopFields() {
  for (const k of ["title", "instructions", ...TOP_NUMBERS]) {
    const p = prop(schemas, BODY, k);
    applyBounds($(k), p);
    const range = $(`${k}-range`);
    if (range) range.textContent = rangeText(p);
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
  form.hidden = false;
  $("exercise").focus();
}

main().catch((e) => {
  $("load-error").textContent = `The form could not be loaded: ${e.message}`;
  $("load-error").hidden = false;
});
