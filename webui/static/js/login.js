import { api, showErrors, signIn } from "./api.js";

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
    location.href = next && next.startsWith("/app/") ? next : "/app/patients";
  } catch (e) {
    showErrors(form, e);
  } finally {
    button.disabled = false;
  }
});
document.getElementById("email").focus();
