// Administrators' page: every account, add one, reset a password, deactivate or reactivate.
// One-time passwords are shown once, as station tokens are; the API enforces every rule.

import { CreateKey, api, currentUser, el, onSubmit, renderHeader, requireSignIn } from "./api.js";
import { confirmButton, showSecret } from "./confirm.js";
import { applyBounds, loadSchemas, prop } from "./schema.js";

await requireSignIn();
renderHeader();

const $ = (id) => document.getElementById(id);
const me = currentUser();
const ROLE_WORDS = { admin: "Administrator", therapist: "Therapist" };

function flash(text) {
  $("flash").textContent = text;
  $("flash").hidden = !text;
}

function statusBadge(u) {
  if (!u.active) return el("span", { class: "badge bad" }, "Deactivated");
  if (u.must_change_password) return el("span", { class: "badge warn" }, "Must change password");
  return el("span", { class: "badge ok" }, "Active");
}

function showPassword(user, password, why) {
  showSecret($("secret-box"), {
    id: "one-time-password",
    noun: "password",
    title: `One-time password for ${user.name}: shown only this once`,
    explain:
      `${why} Give it to ${user.name} (${user.email}) in person or by telephone, not in the same message as the email address. ` +
      "They must choose their own password when they first sign in with it.",
    label: "One-time password",
    value: password,
    after: $("list-title"),
  });
}

function actions(u) {
  if (u.id === me?.id) {
    return [el("a", { href: "/app/password" }, "Change your password")];
  }
  const reset = confirmButton({
    label: "Reset password",
    ariaLabel: `Reset the password of ${u.name}`,
    question: `Reset ${u.name}'s password? They are signed out everywhere and need the new one-time password to sign in.`,
    yes: "Yes, reset",
    no: "Cancel",
    danger: false,
    action: async () => {
      const done = await api(`/users/${u.id}/reset-password`, { method: "POST" });
      await loadList();
      showPassword(done.user, done.one_time_password, "The old password no longer works.");
    },
  });
  const toggle = u.active
    ? confirmButton({
        label: "Deactivate",
        ariaLabel: `Deactivate ${u.name}`,
        question: `Deactivate ${u.name}? They cannot sign in, their open pages stop working and their live views close at once. Their patients and records stay.`,
        yes: "Yes, deactivate",
        no: "Cancel",
        action: async () => {
          await api(`/users/${u.id}/deactivate`, { method: "POST" });
          await loadList();
          flash(`${u.name} is deactivated.`);
          $("list-title").focus();
        },
      })
    : confirmButton({
        label: "Reactivate",
        ariaLabel: `Reactivate ${u.name}`,
        question: `Reactivate ${u.name}? They can sign in again with their password.`,
        yes: "Yes, reactivate",
        no: "Cancel",
        danger: false,
        action: async () => {
          await api(`/users/${u.id}/reactivate`, { method: "POST" });
          await loadList();
          flash(`${u.name} can sign in again.`);
          $("list-title").focus();
        },
      });
  return [reset, toggle];
}

async function loadList() {
  const users = await api("/users");
  $("users").tBodies[0].replaceChildren(
    ...users.map((u) =>
      el(
        "tr",
        { dataset: { userId: u.id } },
        el("th", { scope: "row" }, u.name, u.id === me?.id ? el("span", { class: "muted" }, " (you)") : null),
        el("td", {}, u.email),
        el("td", {}, ROLE_WORDS[u.role] || u.role),
        el("td", {}, statusBadge(u)),
        el("td", {}, el("div", { class: "row" }, ...actions(u))),
      ),
    ),
  );
  $("users").hidden = !users.length;
  $("list-status").textContent = `${users.length} account${users.length === 1 ? "" : "s"}.`;
}

const form = $("add-user");
const createKey = new CreateKey();
onSubmit(form, async () => {
  flash("");
  const f = form.elements;
  const user = await api("/users", {
    method: "POST",
    body: { name: f.name.value, email: f.email.value.trim(), role: f.role.value },
    once: createKey,
  });
  form.reset();
  await loadList();
  showPassword(user, user.one_time_password, `The account of ${user.name} is ready.`);
});

async function main() {
  if (me?.role !== "admin") {
    $("load-error").textContent = "Only an administrator manages accounts.";
    $("load-error").hidden = false;
    $("list-status").textContent = "";
    form.hidden = true;
    return;
  }
  const schemas = await loadSchemas();
  for (const name of ["name", "email"]) applyBounds(form.elements[name], prop(schemas, "UserCreate", name));
  await loadList();
}

main().catch((e) => {
  $("load-error").textContent = `The accounts could not be loaded: ${e.message}`;
  $("load-error").hidden = false;
});
