// The patient's page: what to do now in plain words (one instruction at a time, in #todo),
// pause and STOP, the patient's own progress, and a game steered by the foot (game.js).
// Everything comes from the home station over one WebSocket (webui/home/app.py); the page
// decides nothing about the platform: it asks, and shows what the station says.

import { Game } from "./game.js";

const $ = (id) => document.getElementById(id);
const SAFETY_STOPPED = ["FAULT", "ESTOP"];
// Why the platform holds when it is not the patient's own pause (the station sends the
// reason's code): what happened, in plain words. What to do follows in heldWords.
const HELD_BECAUSE = {
  watchdog: "The platform stopped to keep you safe: it lost contact with this computer for a moment.",
  supply_low: "The platform stopped to keep you safe: its air supply is low.",
  device: "The platform stopped to keep you safe.",
  station: "The platform stopped to keep you safe.",
  therapist: "Your therapist has paused the exercise.",
};
const RUN_PHASES = ["homing", "running", "rest", "paused"];

let socket = null;
let connected = false;
let exercises = [];
let status = null;
let lastProgress = { set: 0, sets: 0, rep: 0, reps: 0, done: 0, total: 0 };
let seq = 0;

// -- the link to the station ------------------------------------------------------------------
function connect() {
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  socket = new WebSocket(`${scheme}://${location.host}/ws`);
  socket.addEventListener("open", () => {
    connected = true;
    render();
  });
  socket.addEventListener("message", (event) => {
    let message;
    try {
      message = JSON.parse(event.data);
    } catch {
      return;
    }
    receive(message);
  });
  socket.addEventListener("close", () => {
    connected = false;
    socket = null;
    status = null; // what the station said is no longer known: the game stops too
    render();
    setTimeout(reconnect, 1000);
  });
}

// Ask over HTTP whether the station is back before opening the socket again: a refused
// WebSocket is an error in the browser's console every second for as long as it is away.
async function reconnect() {
  try {
    const r = await fetch("/", { method: "HEAD", cache: "no-store" });
    if (r.ok) {
      connect();
      return;
    }
  } catch {
    // not back yet
  }
  setTimeout(reconnect, 1000);
}

function send(action) {
  if (!socket || socket.readyState !== WebSocket.OPEN) {
    return false;
  }
  socket.send(JSON.stringify({ ...action, id: String(++seq) }));
  return true;
}

function receive(message) {
  switch (message.type) {
    case "today":
      exercises = message.exercises;
      renderExercises();
      render();
      break;
    case "status":
      status = message;
      render();
      break;
    case "foot":
      game.foot(message.pitch, message.roll);
      showFoot(message.pitch, message.roll);
      break;
    case "progress":
      renderMine(message.lines);
      break;
    case "result":
      answered(message);
      break;
    case "error":
      console.warn("the station did not understand a message:", message.text);
      break;
  }
}

const DONE_WORDS = {
  start: "Starting.", // what to do is said once, in "what to do now"
  pause: "Paused. The platform holds still.",
  resume: "Carrying on.",
  stop: "Stopped. The platform holds still, then goes back slowly to its resting position.",
};

function answered(result) {
  if (result.action === "game_score") {
    return; // a score that arrives after the exercise ended is not worth a word
  }
  feedback(result.ok ? DONE_WORDS[result.action] || "" : `Sorry: ${result.text}.`);
}

let feedbackTimer = 0;
function feedback(text) {
  $("feedback").textContent = text;
  clearTimeout(feedbackTimer);
  if (text) {
    feedbackTimer = setTimeout(() => ($("feedback").textContent = ""), 8000);
  }
}

// -- the page ---------------------------------------------------------------------------------
function setText(el, text) {
  if (el.textContent !== text) {
    el.textContent = text;
  }
}

function setStatus(id, level, text) {
  const el = $(id);
  el.dataset.level = level;
  setText(el.querySelector(".words"), text);
}

function running() {
  return status !== null && RUN_PHASES.includes(status.phase);
}

function currentExercise() {
  if (status && status.prescription_id !== null) {
    return exercises.find((e) => e.id === status.prescription_id) || null;
  }
  return exercises[0] || null;
}

function connectionWords() {
  if (!connected) {
    return ["bad", "This page has lost contact with your station. Trying again…"];
  }
  if (status === null) {
    return ["warn", "Connecting to your station…"];
  }
  const refused = status.refused_uploads || 0;
  if (refused > 0) {
    const which = refused === 1 ? "One session was" : `${refused} sessions were`;
    const kept = refused === 1 ? "It is" : "They are";
    return ["warn", `${which} not accepted by your therapist's server. ${kept} kept safe on this station: please tell your therapist`];
  }
  if (status.online) {
    return ["ok", "Connected to your therapist"];
  }
  return ["warn", "Working offline — your session is saved and will be sent later"];
}

function platformWords() {
  if (!connected || status === null) {
    return ["warn", "Waiting for the platform…"];
  }
  if (status.device === "lost") {
    return ["bad", "The platform is not connected: check that it is switched on and plugged in"];
  }
  const mode = status.device_mode;
  if (SAFETY_STOPPED.includes(mode)) {
    return ["bad", "The platform is stopped for safety: ask for help or call your therapist"];
  }
  // Nothing starts or carries on without air: the light says so, never "ready".
  if (status.supply_low) {
    if (mode === "HOLD") {
      return ["warn", "The platform is holding still because its air supply is low: check that the compressor is on"];
    }
    return ["warn", "The platform's air supply is low: check that the compressor is on"];
  }
  if (mode === "ACTIVE") {
    return ["ok", "The platform is moving with you"];
  }
  if (mode === "HOLD") {
    return ["warn", "The platform is holding still"];
  }
  if (mode === "HOMING") {
    return ["warn", "The platform is moving slowly to its starting position"];
  }
  if (mode === "UNKNOWN") {
    return ["warn", "Waiting for the platform…"];
  }
  return ["ok", "The platform is ready"];
}

// The patient's own pause is theirs to continue; any other hold is not (the station refuses).
function heldByOthers() {
  return status !== null && status.phase === "paused" && status.hold !== null && !status.hold.patient_may_resume;
}

// Coarse on purpose: the line is read out by screen readers whenever it changes.
function endsIn(endsAt) {
  const seconds = endsAt - Date.now() / 1000;
  if (seconds <= 60) {
    return "in less than a minute";
  }
  const minutes = Math.ceil(seconds / 60);
  return `in about ${minutes} minutes`;
}

function heldWords(hold) {
  const what = HELD_BECAUSE[hold.code] || HELD_BECAUSE.device;
  const ends = hold.ends_at ? `the exercise ends by itself ${endsIn(hold.ends_at)}` : "";
  const words = [what, "Keep your foot still."];
  if (hold.code === "therapist") {
    words.push(ends ? `Your therapist will carry it on; if not, ${ends}.` : "Your therapist will carry it on.");
    return words.join(" ");
  }
  if (status.online) {
    const told = "Your therapist has been told and can carry on";
    words.push(ends ? `${told}; if not, ${ends}.` : `${told}.`);
  } else if (ends) {
    words.push(`With no connection to your therapist, ${ends}.`);
  }
  words.push("Press STOP to end it now.");
  return words.join(" ");
}

function todoWords() {
  if (!connected || status === null) {
    return ["warn", "Please wait: the page is connecting to your station."];
  }
  if (SAFETY_STOPPED.includes(status.device_mode) || status.phase === "fault") {
    return [
      "bad",
      "The platform stopped for safety. Take your foot off gently and call your therapist.",
    ];
  }
  if (status.supply_low && !["homing", "running", "rest", "paused"].includes(status.phase)) {
    // Start is off until the air is back: nothing here may say to press it.
    return [
      "warn",
      "The platform's air supply is low. Check that the compressor is switched on and its hose is connected. You can start once the air is back.",
    ];
  }
  const ex = currentExercise();
  switch (status.phase) {
    case "homing":
      return ["warn", "Keep your foot on the plate. The platform is getting ready."];
    case "running":
      // The therapist's words (or the exercise's own), and nowhere else on the page.
      return ["info", (ex && ex.instructions) || "Follow the platform gently."];
    case "rest":
      // The countdown has its own line: announcing it every second would drown the rest.
      return ["ok", "Rest and relax your foot. The next set starts by itself."];
    case "paused":
      if (heldByOthers()) {
        return ["bad", heldWords(status.hold)];
      }
      return ["warn", "Paused. Press Continue when you are ready."];
    case "interrupted":
      if (status.link_lost) {
        // Once the platform answers again, saying to wait for it would keep the patient
        // waiting for nothing.
        const lost = "The exercise ended because the station lost its connection to the platform.";
        if (status.device === "lost") {
          return [
            "warn",
            `${lost} You can start again once the platform is connected, or call your therapist.`,
          ];
        }
        if (status.device_mode === "HOMING") {
          return ["warn", `${lost} It is connected again: keep your foot still while it gets ready.`];
        }
        return [
          "warn",
          `${lost} It is connected again: you can start again when you are ready, or call your therapist.`,
        ];
      }
      return [
        "warn",
        "The exercise ended because the platform was stopped for too long. You can start again when you are ready, or call your therapist.",
      ];
    case "done":
      if (status.starts_again_at) {
        return [
          "ok",
          `Well done! Today's exercise is finished. This demonstration starts again by itself ${endsIn(status.starts_again_at)}; press STOP to keep the platform still.`,
        ];
      }
      return ["ok", "Well done! Today's exercise is finished."];
    case "stopped":
      return ["warn", "The exercise was stopped. You can start again when you are ready."];
  }
  if (status.device === "lost") {
    return ["warn", "Please wait: the platform is not connected yet."];
  }
  if (exercises.length === 0) {
    return ["info", "There is no exercise for today. Your therapist will add one."];
  }
  return ["info", "Put your foot on the plate, then press Start when you are ready."];
}

function renderExercises() {
  const box = $("exercises");
  box.replaceChildren();
  if (exercises.length === 0) {
    const p = document.createElement("p");
    p.className = "quiet";
    p.textContent = "No exercise for today.";
    box.append(p);
    return;
  }
  for (const ex of exercises) {
    const card = document.createElement("article");
    card.className = "exercise-card";
    card.dataset.id = String(ex.id);
    const title = document.createElement("h3");
    title.textContent = ex.title;
    const plan = document.createElement("p");
    plan.className = "plan";
    const sets = ex.sets === 1 ? "1 set" : `${ex.sets} sets`;
    const reps = ex.repetitions === 1 ? "1 repetition" : `${ex.repetitions} repetitions`;
    const minutes = ex.minutes === 1 ? "about 1 minute" : `about ${ex.minutes} minutes`;
    plan.textContent = `${sets} of ${reps}, ${minutes}.`;
    const start = document.createElement("button");
    start.type = "button";
    start.className = "start";
    start.textContent = "Start";
    start.setAttribute("aria-label", `Start ${ex.title}`);
    start.addEventListener("click", () => {
      if (!send({ type: "start", prescription_id: ex.id })) {
        feedback("Sorry: this page is not connected to your station.");
      }
    });
    card.append(title, plan, start);
    box.append(card);
  }
}

function renderProgress() {
  if (status && status.sets > 0) {
    lastProgress = {
      set: status.set,
      sets: status.sets,
      rep: status.rep,
      reps: status.repetitions,
      done: status.reps_done,
      total: status.sets * status.repetitions,
    };
  }
  const p = lastProgress;
  $("progress").hidden = p.total === 0;
  // Once an exercise has ended there is no "current" set or repetition: only what was done.
  const finished = status !== null && status.phase === "done";
  const now = running();
  setText($("set"), finished ? String(p.sets) : now && p.set ? String(p.set) : "–");
  setText($("sets"), String(p.sets));
  setText($("rep"), finished ? String(p.reps) : now && p.rep ? String(p.rep) : "–");
  setText($("reps"), String(p.reps));
  setText($("done"), String(finished ? p.total : p.done));
  setText($("total"), String(p.total));
}

function render() {
  setStatus("connection", ...connectionWords());
  setStatus("platform", ...platformWords());
  const [level, words] = todoWords();
  $("todo").dataset.level = level;
  setText($("todo"), words);

  const resting = status !== null && status.phase === "rest";
  $("rest").hidden = !resting;
  if (resting) {
    setText($("rest-seconds"), String(Math.ceil(status.rest_remaining_s)));
  }
  renderProgress();

  const phase = status ? status.phase : "idle";
  const pause = $("pause");
  const others = heldByOthers();
  pause.hidden = others; // nothing for the patient to continue: only STOP is theirs
  pause.disabled = !connected || !["running", "rest", "paused"].includes(phase) || others;
  setText(pause, phase === "paused" ? "Continue" : "Pause");
  let help = "Pause the exercise. The platform holds still until you continue.";
  if (others) {
    help = "Only your therapist can carry on after this stop.";
  } else if (phase === "paused") {
    const ends = status.hold && status.hold.ends_at ? ` If you do not, it ends by itself ${endsIn(status.hold.ends_at)}.` : "";
    help = `Carry on with the exercise.${ends}`;
  }
  setText($("pause-help"), help);

  const canStart =
    connected &&
    status !== null &&
    status.device === "connected" &&
    !SAFETY_STOPPED.includes(status.device_mode) &&
    !status.supply_low && // the light says why; the station would refuse the start anyway
    !running();
  document.querySelector("main").toggleAttribute("data-running", running());
  for (const card of document.querySelectorAll(".exercise-card")) {
    const mine = running() && status.prescription_id === Number(card.dataset.id);
    card.toggleAttribute("data-running", mine);
    card.querySelector("button.start").disabled = !canStart;
  }

  const details = status && status.message && phase !== "running" ? status.message : "";
  $("details").hidden = !details;
  setText($("message"), details);
  renderGame();
}

// -- the patient's own progress -----------------------------------------------------------------
function renderMine(lines) {
  const list = $("mine-lines");
  list.replaceChildren(
    ...lines.map((line) => {
      const li = document.createElement("li");
      li.textContent = line;
      return li;
    }),
  );
  $("mine").hidden = lines.length === 0;
}

$("pause").addEventListener("click", () => {
  const resume = status !== null && status.phase === "paused";
  send({ type: resume ? "resume" : "pause" });
});

function stop() {
  if (!send({ type: "stop" })) {
    feedback("This page is not connected to your station: use the platform's own stop button.");
  }
}
$("stop").addEventListener("click", stop);
document.addEventListener("keydown", (event) => {
  if (event.key === "Escape") {
    event.preventDefault();
    stop();
  }
});


// -- the game ---------------------------------------------------------------------------------
const game = new Game($("game-canvas"), (g, judged) => {
  setText($("score"), String(g.score));
  setText($("gates"), String(g.count));
  $("game-canvas").setAttribute(
    "aria-label",
    `The game: a plane flies towards gates. Gates passed: ${g.score} of ${g.count}.`,
  );
  if (judged) {
    send({
      type: "game_score",
      session_id: g.session,
      game: g.id,
      score: g.score,
      gates: g.count,
      missed: g.missed,
    });
  }
});

function showFoot(pitch, roll) {
  const words = [];
  const toes = pitch > 0 ? "down" : "up";
  words.push(Math.abs(pitch) < 0.5 ? "level" : `toes ${Math.abs(pitch).toFixed(0)}° ${toes}`);
  if (game.field && game.field.roll && Math.abs(roll) >= 0.5) {
    words.push(`tilted ${Math.abs(roll).toFixed(0)}° ${roll > 0 ? "right" : "left"}`);
  }
  setText($("foot"), `Your foot: ${words.join(", ")}`);
}

function renderGame() {
  const exercise = currentExercise();
  const field = exercise ? exercise.game : null;
  $("game-roll-help").hidden = !(field && field.roll);
  const playing = status !== null && status.phase === "running" && status.device_mode === "ACTIVE";
  game.update(field, status ? status.session_id : null, playing, overlayWords(field));
  let note = "";
  if (!field) {
    note = exercise
      ? "This exercise has no game: the platform holds your foot."
      : "The game starts with your exercise.";
  } else if (!game.playing && running()) {
    note = "The game goes on when the exercise does.";
  } else if (!game.playing) {
    note =
      game.count > 0
        ? "Game over. Your score is saved with today's exercise."
        : "The game starts with your exercise.";
  }
  setText($("game-note"), note);
}

// Drawn over the game when it does not play: the same news as #game-note, on the picture.
function overlayWords(field) {
  const phase = status ? status.phase : "idle";
  if (!field) {
    return "No game in this exercise";
  }
  if (heldByOthers()) {
    return status.hold.code === "therapist" ? "Paused by your therapist" : "Stopped to keep you safe";
  }
  if (phase === "paused") {
    return "Paused";
  }
  if (phase === "rest") {
    return "Resting";
  }
  if (game.count > 0 && !running()) {
    return `Game over: ${game.score} of ${game.count} gates`;
  }
  return "The game starts with your exercise";
}

render();
connect();
game.run();
