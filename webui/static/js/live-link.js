// The live link's socket, in a worker: the heartbeat and the command results keep flowing
// while the page's own thread is busy drawing (the 3D view shares it), so a slow frame never
// costs the therapist the link. Telemetry comes in batches of samples (columns); the page is
// passed every sample, every BATCH_MS; everything else at once.

const HEARTBEAT_MS = 1000;
const BATCH_MS = 50;

let ws = null;
let beat = null;
let flush = null;
let telemetry = [];

function post(items) {
  if (items.length) postMessage({ op: "messages", items });
}

self.addEventListener("message", (ev) => {
  const m = ev.data;
  if (m.op === "open") {
    ws = new WebSocket(m.url, m.protocols);
    ws.addEventListener("open", () => {
      beat = setInterval(() => ws.send(JSON.stringify({ type: "heartbeat", sent: Date.now() / 1000 })), HEARTBEAT_MS);
      flush = setInterval(() => {
        const batch = telemetry;
        telemetry = [];
        post(batch);
      }, BATCH_MS);
      postMessage({ op: "open" });
    });
    ws.addEventListener("message", (e) => {
      const msg = JSON.parse(e.data);
      if (msg.type === "telemetry") {
        // A batch of samples as columns (sessions/wire.py TelemetryBatch): one sample each.
        const n = msg.t.length;
        for (let i = 0; i < n; i++) {
          const sample = { type: "telemetry", sent: msg.sent };
          for (const key in msg) if (Array.isArray(msg[key])) sample[key] = msg[key][i];
          telemetry.push(sample);
        }
        if (telemetry.length > 2000) telemetry.splice(0, telemetry.length - 2000); // 20 s behind: keep the newest
      } else if (msg.type !== "heartbeat") {
        post([...telemetry.splice(0), msg]); // in order: samples before the event that follows
      }
    });
    ws.addEventListener("close", (e) => {
      clearInterval(beat);
      clearInterval(flush);
      post(telemetry.splice(0));
      postMessage({ op: "close", code: e.code, reason: e.reason });
      ws = null;
    });
  } else if (m.op === "send") {
    if (ws && ws.readyState === WebSocket.OPEN) {
      ws.send(JSON.stringify(m.message));
      postMessage({ op: "sent", request_id: m.message.request_id });
    } else {
      postMessage({ op: "unsent", request_id: m.message.request_id });
    }
  }
});
