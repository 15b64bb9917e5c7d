// The dashboard's one way to the server: REST with the signed-in therapist's bearer token,
// errors as ApiError, and small DOM helpers that never put server text into innerHTML.

export const TOKEN_KEY = "ankle.token";
export const USER_KEY = "ankle.user";

export function token() {
  return sessionStorage.getItem(TOKEN_KEY);
}

export function currentUser() {
  const raw = sessionStorage.getItem(USER_KEY);
  return raw ? JSON.parse(raw) : null;
}

export function signIn(tokenPublic) {
  sessionStorage.setItem(TOKEN_KEY, tokenPublic.access_token);
  rememberUser(tokenPublic.user);
}

/** Keep the signed-in user's record (after a sign-in, or a change such as a new password). */
export function rememberUser(user) {
  sessionStorage.setItem(USER_KEY, JSON.stringify(user));
}

export const PASSWORD_PAGE = "/app/password";

/** Where a user whose password was printed or reset goes first, then back to `next`. */
export function passwordUrl(next) {
  return `${PASSWORD_PAGE}?next=${encodeURIComponent(next)}`;
}

export function signOut() {
  sessionStorage.removeItem(TOKEN_KEY);
  sessionStorage.removeItem(USER_KEY);
}

export function loginUrl() {
  return `/app/login?next=${encodeURIComponent(location.pathname + location.search)}`;
}

/** A promise that never settles: what a call returns while the page navigates away. */
const never = () => new Promise(() => {});

/**
 * Send the browser to sign-in unless a token is held. Use as `await requireSignIn();` at the
 * top of a page module: without a token the module waits there while the browser leaves.
 */
export function requireSignIn() {
  if (!token()) {
    location.replace(loginUrl());
    return never();
  }
  // A printed or reset password: the API refuses everything else until it is changed.
  if (currentUser()?.must_change_password && location.pathname !== PASSWORD_PAGE) {
    location.replace(passwordUrl(location.pathname + location.search));
    return never();
  }
  return Promise.resolve();
}

export class ApiError extends Error {
  constructor(status, detail) {
    super(ApiError.text(status, detail));
    this.status = status;
    this.detail = detail;
  }

  static text(status, detail) {
    if (typeof detail === "string") return detail;
    if (Array.isArray(detail)) return detail.map((d) => d.msg).join("; ");
    return `the server answered ${status}`;
  }

  /** FastAPI's 422 items as {"axes.0.stiffness": "Input should be ..."} (the body's path). */
  fieldErrors() {
    const out = {};
    if (!Array.isArray(this.detail)) return out;
    for (const d of this.detail) {
      const loc = (d.loc || []).filter((p, i) => !(i === 0 && p === "body"));
      out[loc.join(".")] = d.msg.replace(/^Value error, /, "");
    }
    return out;
  }
}

// ---- a form's unsaved values across an expired sign-in -------------------------------------
// A 401 sends the page to sign-in, which brings the browser back to the same address. A page
// with a form names how to read its values (keepDraft); they are kept in this tab's
// sessionStorage under the page's address and the user's id, and handed back (takeDraft) once
// the same user has signed in again. Never a password: only forms without one keep a draft.

const DRAFT_KEY = "ankle.draft";
let draftOf = null;

function draftAddress() {
  return location.pathname + location.search;
}

/** Keep ``read()``'s values (any JSON) if the sign-in expires under this page. */
export function keepDraft(read) {
  draftOf = read;
}

function saveDraft() {
  const user = currentUser();
  if (!draftOf || !user) return;
  const draft = { address: draftAddress(), user: user.id, saved: Date.now(), values: draftOf() };
  sessionStorage.setItem(DRAFT_KEY, JSON.stringify(draft));
}

/** The values this page kept when the signed-in user's sign-in expired, or null; taken out
 * of storage (they are now the page's own). */
export function takeDraft() {
  const raw = sessionStorage.getItem(DRAFT_KEY);
  if (!raw) return null;
  let draft = null;
  try {
    draft = JSON.parse(raw);
  } catch (e) {
    /* not ours: dropped below */
  }
  if (draft?.address !== draftAddress()) return null; // another page's: kept for it
  sessionStorage.removeItem(DRAFT_KEY);
  // Someone else signed in on this tab: the draft is not theirs to see.
  return draft.user === currentUser()?.id ? draft : null;
}

/** Forget a kept draft: the page saved its values. */
export function dropDraft() {
  sessionStorage.removeItem(DRAFT_KEY);
}

/** A number input's value for the API: a number, null when empty, or the text "not a number"
 * when the browser could not read what was typed ("1.2.3", or 1e400, past the largest
 * double), which the browser reports as an empty value: it is refused with a sentence, never
 * dropped as if nothing had been typed. */
export function numberValue(input) {
  if (input.value === "") return input.validity.badInput ? "not a number" : null;
  return Number(input.value);
}

/**
 * The Idempotency-Key of one form's create (a patient, a prescription, a station, an account):
 * a fresh one for each new submission, and the same one when the same values are sent again
 * after an attempt whose outcome is unknown (no answer, or a 503), so that the therapist's
 * retry is answered with what the first attempt stored instead of making a second record.
 * Random from crypto.getRandomValues, which, unlike randomUUID, works on a plain-HTTP page.
 */
export class CreateKey {
  #key = null;
  #body = null;

  keyFor(text) {
    if (this.#key === null || this.#body !== text) {
      const bytes = crypto.getRandomValues(new Uint8Array(16));
      this.#key = Array.from(bytes, (b) => b.toString(16).padStart(2, "0")).join("");
      this.#body = text;
    }
    return this.#key;
  }

  /** The attempt ended with ``error`` (null: it succeeded): keep the key only if the
   * outcome is unknown. */
  settled(error) {
    const unknown = error instanceof ApiError && (error.status === 0 || error.status === 503);
    if (!unknown) this.#key = null;
  }
}

/** Call /api/v1{path}; JSON in and out. A 401 ends the sign-in and goes back to it, keeping
 * the page's draft (keepDraft). ``once``: the form's CreateKey, for a create. */
export async function api(path, { method = "GET", body, raw = false, once } = {}) {
  const headers = { Accept: "application/json" };
  const t = token();
  if (t) headers.Authorization = `Bearer ${t}`;
  const init = { method, headers };
  if (body !== undefined) {
    headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  if (once) headers["Idempotency-Key"] = once.keyFor(init.body ?? "");
  try {
    const answer = await send(path, init, raw);
    once?.settled(null);
    return answer;
  } catch (e) {
    once?.settled(e);
    throw e;
  }
}

async function send(path, init, raw) {
  let r;
  try {
    r = await fetch(`/api/v1${path}`, init);
  } catch (e) {
    throw new ApiError(0, "the server cannot be reached: check the network and try again");
  }
  if (r.status === 401 && path !== "/auth/login") {
    // The sign-in has expired: go back to it; the caller's code never resumes.
    saveDraft();
    signOut();
    location.replace(loginUrl());
    return never();
  }
  if (!r.ok) {
    let detail = r.statusText;
    try {
      detail = (await r.json()).detail ?? detail;
    } catch (e) {
      /* not JSON: keep the status text */
    }
    throw new ApiError(r.status, detail);
  }
  if (raw) return r;
  return r.status === 204 ? null : r.json();
}

/**
 * The file name a Content-Disposition header suggests (RFC 6266): filename*=UTF-8''… (RFC 8187,
 * percent-encoded) wins over a plain filename="…"; null when there is none. Only the last
 * path segment is kept: a name never chooses a folder.
 */
export function filenameFrom(header) {
  if (!header) return null;
  const params = {};
  // disposition-type, then ;-separated parameters: token or quoted-string values.
  const re = /;\s*([^\s=;]+)\s*=\s*("(?:[^"\\]|\\.)*"|[^;]*)/g;
  for (let m = re.exec(header); m; m = re.exec(header)) {
    const name = m[1].toLowerCase();
    let value = m[2].trim();
    if (value.startsWith('"')) value = value.slice(1, -1).replace(/\\(.)/g, "$1");
    if (!(name in params)) params[name] = value;
  }
  let name = null;
  const extended = /^([\w!#$%&+^`{}~-]+)'[^']*'(.*)$/.exec(params["filename*"] || "");
  if (extended && extended[1].toLowerCase() === "utf-8") {
    try {
      name = decodeURIComponent(extended[2]);
    } catch (e) {
      name = null; // malformed percent-encoding: fall back to the plain name
    }
  }
  if (!name) name = params.filename || null;
  if (!name) return null;
  name = name.split(/[\\/]/).pop().trim();
  return name && name !== "." && name !== ".." ? name : null;
}

/**
 * Fetch a file with the token and hand it to the browser as a download, under the name the
 * server gives it (Content-Disposition); ``fallback`` only when the server gives none.
 * Returns the name it was saved under.
 */
export async function download(path, fallback) {
  const r = await api(path, { raw: true });
  const filename =
    filenameFrom(r.headers.get("Content-Disposition")) || fallback || path.split("/").pop();
  const blob = await r.blob();
  const url = URL.createObjectURL(blob);
  const a = el("a", { href: url, download: filename });
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
  return filename;
}

/** el("p", {class: "x", onclick: f}, "text", child): text children are text nodes. */
export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === undefined || v === null || v === false) continue;
    if (k.startsWith("on") && typeof v === "function") node.addEventListener(k.slice(2), v);
    else if (k === "class") node.className = v;
    else if (k === "dataset") Object.assign(node.dataset, v);
    else if (v === true) node.setAttribute(k, "");
    else node.setAttribute(k, String(v));
  }
  for (const c of children.flat()) {
    if (c === undefined || c === null || c === false) continue;
    node.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return node;
}

/**
 * Show an ApiError beside the fields it names. A field is any element with
 * data-field="path" (e.g. "axes.0.stiffness") inside the form; its message goes into the
 * element with data-error-for="path", or a new one after the field. Anything unmatched goes
 * to the form's [data-form-error] box.
 */
export function showErrors(form, error) {
  clearErrors(form);
  const box = form.querySelector("[data-form-error]");
  const fields = error instanceof ApiError ? error.fieldErrors() : {};
  const unmatched = [];
  for (const [path, msg] of Object.entries(fields)) {
    const input = form.querySelector(`[data-field="${CSS.escape(path)}"]`);
    if (!input) {
      unmatched.push(path ? `${path}: ${msg}` : msg);
      continue;
    }
    input.setAttribute("aria-invalid", "true");
    let slot = form.querySelector(`[data-error-for="${CSS.escape(path)}"]`);
    if (!slot) {
      slot = el("span", { class: "field-error", "data-error-for": path, role: "alert" });
      input.insertAdjacentElement("afterend", slot);
    }
    slot.id = slot.id || `err-${path.replaceAll(".", "-")}`;
    input.setAttribute("aria-describedby", slot.id);
    slot.textContent = msg;
  }
  if (!Object.keys(fields).length) unmatched.push(error.message || String(error));
  if (box) {
    box.textContent = unmatched.join("; ");
    box.hidden = !unmatched.length;
  }
  const first = form.querySelector('[aria-invalid="true"]');
  if (first) first.focus();
}

/**
 * Run `action(form)` when the form is submitted: its button disabled meanwhile, earlier
 * errors cleared, and an error the action throws shown beside the fields it names.
 */
export function onSubmit(form, action) {
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const button = form.querySelector("button[type=submit]");
    if (button) button.disabled = true;
    clearErrors(form);
    try {
      await action(form);
    } catch (e) {
      showErrors(form, e);
    } finally {
      if (button) button.disabled = false;
    }
  });
}

export function clearErrors(form) {
  for (const n of form.querySelectorAll('[aria-invalid="true"]')) n.removeAttribute("aria-invalid");
  for (const n of form.querySelectorAll("[data-error-for]")) n.textContent = "";
  const box = form.querySelector("[data-form-error]");
  if (box) {
    box.textContent = "";
    box.hidden = true;
  }
}

/** The page header: product name, navigation, who is signed in, sign out. */
export function renderHeader() {
  const user = currentUser();
  const top = document.getElementById("top");
  if (!top) return;
  top.replaceChildren(
    el("a", { class: "brand", href: "/app/patients" }, "Ankle telerehabilitation"),
    el(
      "nav",
      { "aria-label": "Main" },
      el("a", { href: "/app/patients" }, "Patients"),
      user?.role === "admin" ? el("a", { href: "/app/accounts" }, "Accounts") : null,
    ),
    el(
      "div",
      { class: "who" },
      user ? `${user.name} (${user.role})` : "",
      user ? el("a", { href: PASSWORD_PAGE }, "Change password") : null,
      el(
        "button",
        {
          type: "button",
          class: "link",
          onclick: async () => {
            // Signed out on purpose: nothing typed here is kept for later (even if the
            // sign-in had already expired and the server answers 401).
            keepDraft(null);
            dropDraft();
            try {
              await api("/auth/logout", { method: "POST" });
            } catch (e) {
              /* signed out either way */
            }
            signOut();
            location.href = "/app/login";
          },
        },
        "Sign out",
      ),
    ),
  );
}

export const fmt = {
  num(v, digits = 1) {
    return v === null || v === undefined || Number.isNaN(v) ? "–" : Number(v).toFixed(digits);
  },
  date(iso) {
    return iso ? new Date(iso).toLocaleString() : "–";
  },
  day(iso) {
    return iso ? new Date(iso).toLocaleDateString() : "–";
  },
  duration(s) {
    if (s === null || s === undefined) return "–";
    const whole = Math.round(s);
    const h = Math.floor(whole / 3600);
    const m = Math.floor(whole / 60) % 60;
    const r = whole % 60;
    // An hour or more as the API's sentences say it ("338 h 5 min"), not "20285 min 0 s".
    if (h) return [`${h} h`, m ? `${m} min` : "", r ? `${r} s` : ""].filter(Boolean).join(" ");
    return m ? `${m} min ${r} s` : `${r} s`;
  },
  exercise(kind) {
    return (kind || "").replaceAll("_", " ");
  },
};

export const RAD2DEG = 180 / Math.PI;

/** Read an integer id from the page path: /app/patients/12 → pathId(2) === 12. */
export function pathId(index) {
  const part = location.pathname.split("/").filter(Boolean)[index];
  const id = Number.parseInt(part, 10);
  return Number.isFinite(id) ? id : null;
}
