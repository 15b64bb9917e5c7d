// Change your own password; the first stop after signing in with a printed or reset one.

import { ApiError, api, currentUser, el, onSubmit, rememberUser, renderHeader, requireSignIn } from "./api.js";
import { loadSchemas, prop } from "./schema.js";

await requireSignIn();
renderHeader();

const form = document.getElementById("password");
const mustChange = Boolean(currentUser()?.must_change_password);
document.getElementById("must-change").hidden = !mustChange;

function nextPage() {
  const next = new URLSearchParams(location.search).get("next");
  // Only a path on this site, and never this page again: never an open redirect.
  return next && next.startsWith("/app/") && !next.startsWith("/app/password") ? next : "/app/patients";
}

/** A message beside one field, as the API's own 422s are shown. */
function fieldError(field, msg) {
  return new ApiError(422, [{ loc: ["body", field], msg }]);
}

onSubmit(form, async () => {
  const f = form.elements;
  if (f.new_password.value !== f.repeat_password.value) {
    throw fieldError("repeat_password", "this is not the same as the new password");
  }
  let user;
  try {
    user = await api("/auth/password", {
      method: "POST",
      body: { current_password: f.current_password.value, new_password: f.new_password.value },
    });
  } catch (e) {
    // The API's 400 is about the current password; put it beside that field.
    throw e instanceof ApiError && e.status === 400 ? fieldError("current_password", e.message) : e;
  }
  rememberUser(user);
  if (mustChange) {
    location.replace(nextPage()); // a detour on the way in: Back skips it, as it skips sign-in
    return;
  }
  const done = el("p", { class: "notice", role: "status", tabindex: "-1" }, "Your password is changed. ",
    el("a", { href: nextPage() }, "Back to the dashboard"));
  form.replaceWith(done);
  done.focus();
});

try {
  const schemas = await loadSchemas();
  const min = prop(schemas, "PasswordChange", "new_password").minLength;
  if (min) document.getElementById("min-length").textContent = String(min);
} catch (e) {
  /* the help keeps its default; the API checks the length either way */
}
document.getElementById("current_password").focus();
