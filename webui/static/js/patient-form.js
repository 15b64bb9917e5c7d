// The patient's details form, shared by "Add a patient" and "Edit details": its limits come
// from the API's schema and its body is what POST /patients and PATCH /patients/{id} read.

import { el, numberValue } from "./api.js";
import { applyBounds, loadSchemas, prop } from "./schema.js";

export const SIDE_WORDS = { left: "Left", right: "Right", both: "Both" };

/** Bounds and choices from the API's schema on the form's fields. */
export async function setUpPatientForm(form) {
  const schemas = await loadSchemas();
  for (const name of ["display_name", "reference", "birth_year", "weight_kg", "notes"]) {
    applyBounds(form.elements[name], prop(schemas, "PatientCreate", name));
  }
  // The API refuses a birth year in the future; "now" is the one bound it cannot publish.
  form.elements.birth_year.max = String(new Date().getFullYear());
  const sides = form.elements.affected_side;
  for (const side of prop(schemas, "PatientCreate", "affected_side").enum) {
    sides.append(el("option", { value: side }, SIDE_WORDS[side] || side));
  }
}

/** The form's values as the API's body. */
export function patientBody(form) {
  const f = form.elements;
  const text = (v) => (v.trim() === "" ? null : v.trim());
  return {
    display_name: f.display_name.value,
    reference: text(f.reference.value),
    birth_year: numberValue(f.birth_year),
    affected_side: f.affected_side.value || null,
    weight_kg: numberValue(f.weight_kg),
    notes: f.notes.value,
  };
}

/** Put a patient's details into the form. */
export function fillPatientForm(form, p) {
  const f = form.elements;
  f.display_name.value = p.display_name;
  f.reference.value = p.reference ?? "";
  f.birth_year.value = p.birth_year ?? "";
  f.affected_side.value = p.affected_side ?? "";
  f.weight_kg.value = p.weight_kg ?? "";
  f.notes.value = p.notes ?? "";
}
