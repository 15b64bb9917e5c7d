// The API's own published limits, read from its OpenAPI document so a form's min, max and
// maxlength can never drift from what the server enforces.

import { api } from "./api.js";

let cached = null;

/** The OpenAPI document's component schemas, fetched once per page. */
export async function loadSchemas() {
  if (!cached) cached = api("/openapi.json").then((doc) => doc.components.schemas);
  return cached;
}

/** One property of a component schema; for "X or null" the X branch. */
export function prop(schemas, model, field) {
  const p = schemas[model]?.properties?.[field];
  if (!p) throw new Error(`the API publishes no ${model}.${field}`);
  if (p.anyOf) {
    const branch = p.anyOf.find((b) => b.type !== "null");
    return { ...branch, title: p.title, description: p.description, default: p.default };
  }
  if (p.$ref) return { ...schemas[p.$ref.split("/").pop()], ...p };
  return p;
}

/** min / max / maxlength attributes for an input, from a property's bounds. */
export function boundsAttrs(p) {
  const attrs = {};
  const min = p.minimum ?? p.exclusiveMinimum;
  if (min !== undefined) attrs.min = min;
  if (p.maximum !== undefined) attrs.max = p.maximum;
  if (p.maxLength !== undefined) attrs.maxlength = p.maxLength;
  return attrs;
}

/** Put a property's bounds on an existing input. */
export function applyBounds(input, p) {
  for (const [k, v] of Object.entries(boundsAttrs(p))) input.setAttribute(k, String(v));
}

/** "0 to 500" for a help text, with the exclusive lower bound marked. */
export function rangeText(p) {
  const lo = p.minimum ?? p.exclusiveMinimum;
  const hi = p.maximum;
  if (lo === undefined && hi === undefined) return "";
  const low = p.exclusiveMinimum !== undefined ? `above ${lo}` : `${lo}`;
  if (hi === undefined) return `at least ${low}`;
  if (lo === undefined) return `up to ${hi}`;
  // "to", not a dash: "-90–90" reads as a subtraction
  return p.exclusiveMinimum !== undefined ? `${low}, up to ${hi}` : `${lo} to ${hi}`;
}
