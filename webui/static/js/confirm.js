// Two small patterns the pages share: a secret shown only once (a station's token, a
// one-time password), and an action that asks "are you sure?" in place before it runs.

import { el } from "./api.js";

/**
 * Fill `box` with a secret to copy now: a heading, what to do with it, the value selected in
 * a read-only field, Copy, and a button that hides it (focus then goes to `after`). `noun`
 * names it on the buttons ("token", "password").
 */
export function showSecret(box, { id, noun, title, explain, label, value, after }) {
  const input = el("input", { id, readonly: true, value, class: "pt-token-value", spellcheck: "false" });
  const status = el("span", { class: "small", role: "status" });
  box.replaceChildren(
    el("h3", {}, title),
    el("p", {}, explain),
    el("label", { for: id }, label),
    input,
    el(
      "div",
      { class: "row pt-token-actions" },
      el("button", { type: "button", class: "secondary", onclick: () => copy(input, status) }, `Copy ${noun}`),
      el("button", { type: "button", onclick: () => hide(box, after) }, `I have saved it: hide the ${noun}`),
      status,
    ),
  );
  box.hidden = false;
  box.focus();
  input.select();
}

function hide(box, after) {
  box.replaceChildren();
  box.hidden = true;
  if (after) after.focus();
}

async function copy(input, status) {
  input.select();
  try {
    await navigator.clipboard.writeText(input.value);
    status.textContent = "Copied.";
  } catch (e) {
    // Clipboard access needs a secure page; the text is selected for Ctrl+C instead.
    status.textContent = "Press Ctrl+C to copy the selected text.";
  }
}

/**
 * A button that, when pressed, is replaced in place by `question`, a confirming button and
 * a way back; the confirmation runs `action` and shows its error beside the buttons. While
 * it asks, the slot carries `data-confirming` (a page that redraws itself waits).
 * Returns the element to put on the page.
 */
export function confirmButton({ label, ariaLabel, question, yes, no = "Cancel", danger = true, action }) {
  const slot = el("span", { class: "row" });
  const ask = el("button", { type: "button", class: danger ? "danger" : "secondary", "aria-label": ariaLabel }, label);
  ask.addEventListener("click", () => {
    const back = el("button", { type: "button", class: "secondary" }, no);
    const go = el("button", { type: "button", class: danger ? "danger" : "" }, yes);
    const error = el("span", { class: "field-error", role: "alert" });
    back.addEventListener("click", () => {
      delete slot.dataset.confirming;
      slot.replaceChildren(ask);
      ask.focus();
    });
    go.addEventListener("click", async () => {
      go.disabled = true;
      try {
        await action();
      } catch (e) {
        error.textContent = e.message;
        go.disabled = false;
      }
    });
    slot.dataset.confirming = "";
    slot.replaceChildren(el("span", {}, question), go, back, error);
    go.focus();
  });
  slot.append(ask);
  return slot;
}
