// The game on the patient's page: a plane flies away from the patient towards gates; ankle
// pitch moves it up and down, roll left and right. Positions are in the field's units: -1..1
// across what the exercise allows (the station sends the field, webui/home/game.py). The page
// (home.js) says when it plays and what to write over it when it does not; the game draws,
// judges the gates and reports each result through `onScore`.

const GATE_EVERY_S = 2.5;
const APPROACH_S = 3.5;
const OPENING = 0.3; // half the gate's opening
const DEPTH = 5; // perspective: a gate at the far end is drawn 1/(1+DEPTH) of its size

export class Game {
  constructor(canvas, onScore) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.onScore = onScore;
    this.field = null;
    this.session = null;
    this.id = 0;
    this.playing = false;
    this.overlay = "";
    this.clock = 0;
    this.nextGate = 0;
    this.gates = [];
    this.score = 0;
    this.count = 0;
    this.missed = 0;
    this.plane = { x: 0, y: 0 };
    this.sides = { x: 1, y: 1 };
    this.flash = null;
    this.spawned = 0;
  }

  // What the page knows now: the exercise's field, its session, whether the exercise moves
  // (the game plays only then) and the words drawn over a game that does not play.
  update(field, session, playing, overlay) {
    this.field = field;
    if (session && session !== this.session) {
      this.reset(session);
    } else if (!session && this.gates.length) {
      this.gates = []; // the exercise has ended: so has the game, with its score kept
    }
    this.playing = playing && !!field;
    this.overlay = overlay;
  }

  reset(session) {
    this.session = session;
    this.id = 1 + Math.floor(Math.random() * 2_000_000_000);
    this.clock = 0;
    this.nextGate = 0.5;
    this.gates = [];
    this.spawned = 0;
    this.score = this.count = this.missed = 0;
    this.onScore(this, false);
  }

  axis(value, range) {
    if (!range) {
      return 0; // the exercise holds this axis still: so does the plane
    }
    const mid = (range[0] + range[1]) / 2;
    const half = (range[1] - range[0]) / 2;
    return Math.max(-1.15, Math.min(1.15, (value - mid) / half));
  }

  foot(pitch, roll) {
    if (this.field) {
      // Toes down (pitch > 0) flies lower; the screen's y grows downwards.
      this.plane = { x: this.axis(roll, this.field.roll), y: this.axis(pitch, this.field.pitch) };
    }
  }

  place(axisRange, side, flip) {
    if (!axisRange) {
      return 0;
    }
    // Alternate sides so that the gates lead the foot through its range, as the exercise does.
    if (flip) {
      this.sides[side] = -this.sides[side];
    }
    return this.sides[side] * (0.25 + Math.random() * (0.7 - 0.25));
  }

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
  }

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
    this.onScore(this, true);
  }

  // -- drawing ----------------------------------------------------------------------------
  fit() {
    const canvas = this.canvas;
    const ratio = window.devicePixelRatio || 1;
    const w = Math.round(canvas.clientWidth * ratio);
    const h = Math.round(canvas.clientHeight * ratio);
    if (w > 0 && h > 0 && (canvas.width !== w || canvas.height !== h)) {
      canvas.width = w;
      canvas.height = h;
    }
  }

  draw() {
    this.fit();
    const { canvas, ctx } = this;
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
      const z = 1 - (((this.clock / APPROACH_S) * 2 + i / 6) % 1);
      const y = cy + (H - cy) / (1 + DEPTH * z);
      ctx.beginPath();
      ctx.moveTo(0, y);
      ctx.lineTo(W, y);
      ctx.stroke();
    }

    // How to steer, on the game itself (the page's one instruction is about the exercise).
    ctx.fillStyle = "#1b1f24";
    ctx.font = "600 16px system-ui, sans-serif";
    if (this.field && this.field.pitch) {
      ctx.textAlign = "left";
      ctx.fillText("toes up: fly higher ↑", 10, 22);
      ctx.fillText("toes down: fly lower ↓", 10, H - 12);
    }
    if (this.field && this.field.roll) {
      ctx.textAlign = "right";
      ctx.fillText("tilt your foot to steer ↔", W - 10, 22);
    }

    const gates = [...this.gates].sort((a, b) => a.born - b.born);
    for (let i = gates.length - 1; i >= 0; i--) {
      const gate = gates[i];
      const z = Math.max(0, 1 - (this.clock - gate.born) / APPROACH_S);
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

    this.drawPlane(cx + this.plane.x * R, cy + this.plane.y * R, this.plane.x * 0.35, R);

    const now = performance.now();
    if (this.flash && now < this.flash.until) {
      ctx.font = "700 44px system-ui, sans-serif";
      ctx.textAlign = "center";
      ctx.lineWidth = 6;
      ctx.strokeStyle = "#ffffff";
      const text = this.flash.good ? "Great!" : "Missed";
      ctx.strokeText(text, cx, 60);
      ctx.fillStyle = this.flash.good ? "#0b6b2e" : "#b00020";
      ctx.fillText(text, cx, 60);
    }
    if (!this.playing && this.overlay) {
      ctx.font = "700 26px system-ui, sans-serif";
      const w = Math.min(W - 16, ctx.measureText(this.overlay).width + 48);
      ctx.fillStyle = "rgba(255,255,255,0.88)";
      ctx.strokeStyle = "#1b1f24";
      ctx.lineWidth = 2;
      ctx.beginPath();
      ctx.roundRect(cx - w / 2, H * 0.2 - 30, w, 56, 10);
      ctx.fill();
      ctx.stroke();
      ctx.fillStyle = "#111";
      ctx.textAlign = "center";
      ctx.fillText(this.overlay, cx, H * 0.2 + 8, W - 40);
    }
  }

  drawPlane(x, y, bank, R) {
    const ctx = this.ctx;
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

  // Draws every frame; the game advances only while it plays.
  run() {
    let last = performance.now();
    const frame = (now) => {
      const dt = Math.min(0.1, (now - last) / 1000);
      last = now;
      this.step(dt);
      this.draw();
      requestAnimationFrame(frame);
    };
    requestAnimationFrame(frame);
  }
}
