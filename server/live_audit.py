"""The audit trail of a therapist's live commands: K/B, HOLD, Resume, Stop and Start.

The log is append-only, so a command leaves two rows linked by its ``request_id`` rather
than one row that is later corrected:

- ``<kind>.request`` when it is sent: who asked, which station and patient, what was asked.
  Resume, Start and K/B, which make the platform move or change what the patient feels, are
  sent only once this row is committed: a command that cannot be audited, or not within
  ``server.hub.AUDIT_WAIT_S`` of its arrival, is not sent. HOLD and Stop are never delayed
  or refused for the database: their row is queued before they go out and written beside.
- its outcome: ``<kind>.accepted`` (K/B: ``impedance.change``, the only row that says the
  values changed; its old and new values are the station's own account of the change, the
  very values the session's event log records, and say when it applies), ``<kind>.refused``
  with the code, field and reason of whoever refused it (the device's NACK, the station, or
  the server itself: ``FORBIDDEN``, ``OFFLINE``, ``DUPLICATE``, ``AUDIT``, ``REFUSED`` for a
  Start of no prescription or of one not active for the station's patient, ``SUPERSEDED``
  for one a HOLD or Stop passed while it waited, ``BUSY``; a command the server refuses is
  never sent and has no request row, unless the viewer's process had sent it on to the
  station's, which refused it, or it was refused after its request row was queued:
  ``SUPERSEDED``, or ``AUDIT`` for a row the database did not take in time, which it may
  still take late, before the refusal row), or ``<kind>.unanswered`` (``TIMEOUT``, the
  station's link lost, the server shut down; or the station's process never said that the
  command ended, and the viewer's process ended it): what the device did is not known. An
  answer that arrives after its TIMEOUT still writes its outcome, marked ``late``.

A command from a viewer on another server process has its request row written by that
process and its outcome by the station's (:mod:`server.hub`).

The server's own refusals of one user's commands to one station past a few a second are
counted rather than written one by one: one ``command.refusals`` row says how many
(:class:`server.hub.Refusals`).

A link that took over a live one of another run of the station program, or a station saying
its own was taken over, is one station token used by two stations: a ``station.token_shared``
row (:data:`TOKEN_SHARED_ACTION`; at most 6 an hour per station, ``Hub.token_shared``).

``kind`` is ``impedance`` (``set_impedance``), ``hold``, ``resume``, ``stop`` or ``start``.
Rows go through the hub's batched writer; outcomes are queued, never awaited, so a station's
answer costs the relay no database round trip.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from sessions import wire

Outcome = Literal["accepted", "refused", "unanswered"]
Phase = Literal["request", "accepted", "refused", "unanswered"]

KIND: dict[str, str] = {
    "set_impedance": "impedance",
    "hold": "hold",
    "resume": "resume",
    "stop": "stop",
    "start": "start",
}
"""The audit name of each command action."""
TOKEN_SHARED_ACTION = "station.token_shared"
"""Two stations were found using one station token (``new``: how it was seen)."""
SAFE_ACTIONS = frozenset({"hold", "stop"})
"""Commands that take motion away: sent at once, their request row written beside them."""
UNANSWERED_CODES = frozenset({"TIMEOUT"})
"""Codes in a station's answer that mean the device never answered (it may have acted)."""


def action(command: str, phase: Phase) -> str:
    """The audit action of one row about a command (``hold.request``, ``impedance.change``)."""
    kind = KIND[command]
    if kind == "impedance" and phase == "accepted":
        return "impedance.change"
    return f"{kind}.{phase}"


def outcome_of(result: wire.CommandResult) -> Outcome:
    """What a station's answer means for the record."""
    if result.ok:
        return "accepted"
    return "unanswered" if result.code in UNANSWERED_CODES else "refused"


@dataclass(frozen=True)
class Asked:
    """One command as the audit log tells it: everything its rows need."""

    actor: str
    station_id: int
    patient_id: int | None
    command: wire.Command

    def what(self) -> dict[str, Any]:
        """What was asked, with the request_id that links the rows."""
        cmd = self.command
        asked: dict[str, Any] = {"request_id": cmd.request_id}
        if cmd.action == "set_impedance":
            asked |= {"stiffness": cmd.stiffness or {}, "damping": cmd.damping or {}}
        elif cmd.action == "start":
            asked["prescription_id"] = cmd.prescription_id
        return asked

    def _row(self, phase: Phase, old: Any, new: dict[str, Any]) -> dict[str, Any]:
        return {
            "actor": self.actor,
            "action": action(self.command.action, phase),
            "entity": "station",
            "entity_id": self.station_id,
            "patient_id": self.patient_id,
            "old": old,
            "new": new,
        }

    def request_row(self) -> dict[str, Any]:
        return self._row("request", None, self.what())

    def outcome_row(
        self, outcome: Outcome, result: wire.CommandResult, late: bool = False
    ) -> dict[str, Any]:
        """The outcome. A K/B change the station made is recorded as it says it made it: the
        old and new values of the session's own event (``wire.ImpedanceChange``), and when
        it applies; ``old`` is None for anything else."""
        answer: dict[str, Any] = {"code": result.code, "field": result.field, "text": result.text}
        if late:
            answer["late"] = True
        change = result.change if outcome == "accepted" else None
        if change is None:
            return self._row(outcome, None, self.what() | answer)
        made = change.new.model_dump() | {"applies": change.applies}
        return self._row(outcome, change.old.model_dump(), self.what() | made | answer)
