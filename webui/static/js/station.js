// The patient's page: what to do now in plain words, pause and STOP, and a game steered by
// the foot. Everything comes from the home station over one WebSocket (webui/patient.py);
// the page decides nothing about the platform: it asks, and shows what the station says.

const $ = (id) => document.getElementById(id);

// What to do while a repetition runs, by exercise. The therapist's own instructions are on
// the exercise card; these are the short reminders for this moment.
const DOING = {
  strength: "Push your foot against the plate: toes down, then up. Slowly.",
  flexibility: "Relax and let the platform move your foot. Help it along if you can.",
  passive_rom: "Keep your foot relaxed. The platform moves it for you.",
  isometric: "Push your toes down against the plate and hold. It will not move.",
  balance: "Keep the plate level with small, steady movements.",
  rom_assessment: "Move your foot as far as is comfortable: toes down, up, in and out.",
};
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
  start: "Starting. Keep your foot on the plate.",
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
  const ex = currentExercise();
  switch (status.phase) {
    case "homing":
      return ["warn", "Keep your foot on the plate. The platform is getting ready."];
    case "running":
      return ["info", (ex && DOING[ex.exercise]) || "Follow the platform gently."];
    case "rest":
      // The countdown has its own line: announcing it every second would drown the rest.
      return ["ok", "Rest and relax your foot. The next set starts by itself."];
    case "paused":
      if (heldByOthers()) {
        return ["bad", heldWords(status.hold)];
      }
      return ["warn", "Paused. Press Continue when you are ready."];
    case "interrupted":
      return [
        "warn",
        "The exercise ended because the platform was stopped for too long. You can start again when you are ready, or call your therapist.",
      ];
    case "done":
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
    const instructions = document.createElement("p");
    instructions.className = "instructions";
    instructions.textContent = ex.instructions;
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
    card.append(title, instructions, plan, start);
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
    !running();
  for (const card of document.querySelectorAll(".exercise-card")) {
    const mine = running() && status.prescription_id === Number(card.dataset.id);
    card.toggleAttribute("data-running", mine);
    card.querySelector("button.start").disabled = !canStart;
  }

  const details = status && status.message && phase !== "running" ? status.message : "";
  $("details").hidden = !details;
  setText($("message"), details);
  game.status(status, currentExercise());
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
// A plane flies away from the patient towards gates; ankle pitch moves it up and down, roll
// left and right. Positions are in the field's units: -1..1 across what the exercise allows.
const GATE_EVERY_S = 2.5;
const APPROACH_S = 3.5;
const OPENING = 0.3; // half the gate's opening
const DEPTH = 5; // perspective: a gate at the far end is drawn 1/(1+DEPTH) of its size

const game = {
  field: null,
  session: null,
  id: 0,
  playing: false,
  clock: 0,
  nextGate: 0,
  gates: [],
  score: 0,
  count: 0,
  missed: 0,
  plane: { x: 0, y: 0 },
  sides: { x: 1, y: 1 },
  flash: null,
  spawned: 0,

  status(st, exercise) {
    this.field = exercise ? exercise.game : null;
    $("game-roll-help").hidden = !(this.field && this.field.roll);
    const session = st ? st.session_id : null;
    if (session && session !== this.session) {
      this.reset(session);
    } else if (!session && this.gates.length) {
      this.gates = []; // the exercise has ended: so has the game, with its score kept
    }
    this.playing =
      st !== null && st.phase === "running" && st.device_mode === "ACTIVE" && !!this.field;
    let note = "";
    if (!this.field) {
      note = exercise
        ? "This exercise has no game: the platform holds your foot."
        : "The game starts with your exercise.";
    } else if (!this.playing && running()) {
      note = "The game goes on when the exercise does.";
    } else if (!this.playing) {
      note =
        this.count > 0
          ? "Game over. Your score is saved with today's exercise."
          : "The game starts with your exercise.";
    }
    setText($("game-note"), note);
  },

  reset(session) {
    this.session = session;
    this.id = 1 + Math.floor(Math.random() * 2_000_000_000);
    this.clock = 0;
    this.nextGate = 0.5;
    this.gates = [];
    this.spawned = 0;
    this.score = this.count = this.missed = 0;
    this.showScore();
  },

  axis(value, range) {
    if (!range) {
      return 0; // the exercise holds this axis still: so does the plane
    }
    const mid = (range[0] + range[1]) / 2;
    const half = (range[1] - range[0]) / 2;
    return Math.max(-1.15, Math.min(1.15, (value - mid) / half));
  },

  foot(pitch, roll) {
    if (this.field) {
      // Toes down (pitch > 0) flies lower; the screen's y grows downwards.
      this.plane = { x: this.axis(roll, this.field.roll), y: this.axis(pitch, this.field.pitch) };
    }
    const words = [];
    const toes = pitch > 0 ? "down" : "up";
    words.push(Math.abs(pitch) < 0.5 ? "level" : `toes ${Math.abs(pitch).toFixed(0)}° ${toes}`);
    if (this.field && this.field.roll && Math.abs(roll) >= 0.5) {
      words.push(`tilted ${Math.abs(roll).toFixed(0)}° ${roll > 0 ? "right" : "left"}`);
    }
    setText($("foot"), `Your foot: ${words.join(", ")}`);
  },

  place(axisRange, side, flip) {
    if (!axisRange) {
      return 0;
    }
    // Alternate sides so that the gates lead the foot through its range, as the exercise does.
    if (flip) {
      this.sides[side] = -this.sides[side];
    }
    return this.sides[side] * (0.25 + Math.random() * (0.7 - 0.25));
  },

  step(dt) {
    if (!this.playing) {
      return;
    }
    this.clock += dt;
    if (this.clock >= this.nextGate) {
      // Up and down every gate, left and right every other one: all four corners in turn.
      this.spawned += 1;
      this.gates.push({
        x: this.place(this.field.roll, "x", this.spawned % 2 === 0),
        y: this.place(this.field.pitch, "y", true),
        born: this.clock,
      });
      this.nextGate = this.clock + GATE_EVERY_S;
    }
    for (const gate of [...this.gates]) {
      if (this.clock - gate.born >= APPROACH_S) {
        this.judge(gate);
      }
    }
  },

  judge(gate) {
    this.gates.splice(this.gates.indexOf(gate), 1);
    const inside =
      Math.abs(this.plane.x - gate.x) <= OPENING && Math.abs(this.plane.y - gate.y) <= OPENING;
    this.count += 1;
    if (inside) {
      this.score += 1;
    } else {
      this.missed += 1;
    }
    this.flash = { good: inside, until: performance.now() + 900 };
    this.showScore();
    send({
      type: "game_score",
      session_id: this.session,
      game: this.id,
      score: this.score,
      gates: this.count,
      missed: this.missed,
    });
  },

  showScore() {
    setText($("score"), String(this.score));
    setText($("gates"), String(this.count));
    $("game-canvas").setAttribute(
      "aria-label",
      `The game: a plane flies towards gates. Gates passed: ${this.score} of ${this.count}.`,
    );
  },
};

// -- drawing the game -------------------------------------------------------------------------
const canvas = $("game-canvas");
const ctx = canvas.getContext("2d");

function fitCanvas() {
  const ratio = window.devicePixelRatio || 1;
  const w = Math.round(canvas.clientWidth * ratio);
  const h = Math.round(canvas.clientHeight * ratio);
  if (w > 0 && h > 0 && (canvas.width !== w || canvas.height !== h)) {
    canvas.width = w;
    canvas.height = h;
  }
}

function draw() {
  fitCanvas();
  const ratio = canvas.width / Math.max(1, canvas.clientWidth);
  const W = canvas.clientWidth;
  const H = canvas.clientHeight;
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  const cx = W / 2;
  const cy = H / 2;
  const R = Math.min(W, H) * 0.4;

  const sky = ctx.createLinearGradient(0, 0, 0, cy);
  sky.addColorStop(0, "#5aa9e6");
  sky.addColorStop(1, "#cfe9ff");
  ctx.fillStyle = sky;
  ctx.fillRect(0, 0, W, cy);
  ctx.fillStyle = "#5f9e48";
  ctx.fillRect(0, cy, W, H - cy);
  // Stripes on the ground rush towards the patient while the plane flies.
  ctx.strokeStyle = "rgba(255,255,255,0.35)";
  ctx.lineWidth = 2;
  for (let i = 0; i < 6; i++) {
    const z = 1 - (((game.clock / APPROACH_S) * 2 + i / 6) % 1);
    const y = cy + (H - cy) / (1 + DEPTH * z);
    ctx.beginPath();
    ctx.moveTo(0, y);
    ctx.lineTo(W, y);
    ctx.stroke();
  }

  ctx.fillStyle = "#1b1f24";
  ctx.font = "600 15px system-ui, sans-serif";
  ctx.textAlign = "left";
  if (game.field && game.field.pitch) {
    ctx.fillText("toes up ↑", 10, 22);
    ctx.fillText("toes down ↓", 10, H - 12);
  }

  const gates = [...game.gates].sort((a, b) => a.born - b.born);
  for (let i = gates.length - 1; i >= 0; i--) {
    const gate = gates[i];
    const z = Math.max(0, 1 - (game.clock - gate.born) / APPROACH_S);
    const s = 1 / (1 + DEPTH * z);
    const gx = cx + gate.x * R * s;
    const gy = cy + gate.y * R * s;
    const half = OPENING * R * s;
    ctx.lineWidth = Math.max(3, 14 * s);
    ctx.strokeStyle = i === 0 ? "#ff8c00" : "#ffffff";
    ctx.strokeRect(gx - half, gy - half, 2 * half, 2 * half);
    ctx.lineWidth = Math.max(1, 3 * s);
    ctx.strokeStyle = "#1b1f24";
    ctx.strokeRect(gx - half - 7 * s, gy - half - 7 * s, 2 * half + 14 * s, 2 * half + 14 * s);
  }

  drawPlane(cx + game.plane.x * R, cy + game.plane.y * R, game.plane.x * 0.35, R);

  const now = performance.now();
  if (game.flash && now < game.flash.until) {
    ctx.font = "700 44px system-ui, sans-serif";
    ctx.textAlign = "center";
    ctx.lineWidth = 6;
    ctx.strokeStyle = "#ffffff";
    const text = game.flash.good ? "Great!" : "Missed";
    ctx.strokeText(text, cx, 60);
    ctx.fillStyle = game.flash.good ? "#0b6b2e" : "#b00020";
    ctx.fillText(text, cx, 60);
  }
  if (!game.playing) {
    const words = overlayWords();
    ctx.font = "700 26px system-ui, sans-serif";
    const w = ctx.measureText(words).width + 48;
    ctx.fillStyle = "rgba(255,255,255,0.88)";
    ctx.strokeStyle = "#1b1f24";
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.roundRect(cx - w / 2, H * 0.2 - 30, w, 56, 10);
    ctx.fill();
    ctx.stroke();
    ctx.fillStyle = "#111";
    ctx.textAlign = "center";
    ctx.fillText(words, cx, H * 0.2 + 8);
  }
}

function overlayWords() {
  const phase = status ? status.phase : "idle";
  if (!game.field) {
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

function drawPlane(x, y, bank, R) {
  const span = R * 0.5;
  ctx.save();
  ctx.translate(x, y);
  ctx.rotate(bank);
  ctx.lineJoin = "round";
  ctx.fillStyle = "#d0001b";
  ctx.strokeStyle = "#111";
  ctx.lineWidth = 3;
  // wings
  ctx.beginPath();
  ctx.moveTo(-span, 6);
  ctx.lineTo(0, -4);
  ctx.lineTo(span, 6);
  ctx.lineTo(0, 12);
  ctx.closePath();
  ctx.fill();
  ctx.stroke();
  // tail fin
  ctx.beginPath();
  ctx.moveTo(-6, -2);
  ctx.lineTo(0, -span * 0.45);
  ctx.lineTo(6, -2);
  ctx.closePath();
  ctx.fill();
  ctx.stroke();
  // body, seen from behind
  ctx.fillStyle = "#ffffff";
  ctx.beginPath();
  ctx.arc(0, 4, span * 0.16, 0, Math.PI * 2);
  ctx.fill();
  ctx.stroke();
  ctx.restore();
}

let last = performance.now();
function frame(now) {
  const dt = Math.min(0.1, (now - last) / 1000);
  last = now;
  game.step(dt);
  draw();
  requestAnimationFrame(frame);
}

render();
connect();
requestAnimationFrame(frame);
