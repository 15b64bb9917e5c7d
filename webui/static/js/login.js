import { api, passwordUrl, showErrors, signIn } from "./api.js";

const form = document.getElementById("login");
form.addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const button = form.querySelector("button[type=submit]");
  button.disabled = true;
  try {
    const tok = await api("/auth/login", {
      method: "POST",
      body: { email: form.email.value.trim(), password: form.password.value },
    });
    signIn(tok);
    const next = new URLSearchParams(location.search).get("next");
    // Only a path on this site: never an open redirect.
    const target = next && next.startsWith("/app/") ? next : "/app/patients";
    // A printed or reset password is changed first; the API refuses the rest until then.
    // The sign-in page replaces itself in the history: Back from the page it leads to goes
    // where the therapist was before, not to a sign-in form while signed in.
    location.replace(tok.user.must_change_password ? passwordUrl(target) : target);
  } catch (e) {
    showErrors(form, e);
  } finally {
    button.disabled = false;
  }
});
document.getElementById("email").focus();
