// Status words shared by the patient pages: a station's link and a session's ending.

import { el, fmt } from "./api.js";

const END_REASON = {
  completed: ["ok", "Completed"],
  stopped: ["warn", "Stopped early"],
  interrupted: ["warn", "Interrupted"],
  fault: ["bad", "Fault"],
};

export function endReasonBadge(reason) {
  if (!reason) return el("span", { class: "badge offline" }, "Not finished");
  const [cls, word] = END_REASON[reason] || ["offline", reason];
  return el("span", { class: `badge ${cls}` }, word);
}

export function stationBadge(station) {
  if (station.revoked) return el("span", { class: "badge bad" }, "Revoked");
  return station.online
    ? el("span", { class: "badge online", title: "Connected now" }, "Online")
    : el(
        "span",
        { class: "badge offline", title: station.last_seen_at ? `Last seen ${fmt.date(station.last_seen_at)}` : "Never connected" },
        "Offline",
      );
}

const ATTENTION = {
  fault: ["bad", "Fault"],
  held: ["warn", "Held"],
  ended_early: ["warn", "Ended early"],
  data_missing: ["warn", "Data missing"],
  missed: ["warn", "Sessions missed"],
  offline: ["offline", "Station offline"],
  token_shared: ["bad", "Token used twice"],
};

/** What kind of thing needs attention (GET /patients/attention's kind), as a badge. */
export function attentionBadge(kind) {
  const [cls, word] = ATTENTION[kind] || ["offline", kind];
  return el("span", { class: `badge ${cls}` }, word);
}
