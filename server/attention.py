"""What needs a therapist's attention: the one place that decides it, for the patients list.

From the last :data:`LOOKBACK_DAYS` days of the therapist's current patients: sessions with a
fault, sessions held, sessions ended early (stopped, interrupted, or completed with fewer
repetitions than prescribed), active prescriptions with sessions missed in a prescribed week
that ended in those days (``sessions.progress.missed_weeks``: the weeks and counts of the
progress page's adherence, so the two never disagree), home stations not seen for
:data:`OFFLINE_DAYS` days, and stations whose token another station used in those days (the
live hub's ``station.token_shared`` audit rows: the platform the therapist watched may not
have been the patient's). Each item says what happened in a sentence and links to where it
happened: the session's review page, or the patient's page (their prescriptions and
stations).

Five queries whatever the number of patients and sessions (the patients' names, sessions
with their stored summaries, active prescriptions, their sessions of the last two weeks,
stations, stations whose token two stations used), plus one look-up of which stations are
connected now.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Iterable
from datetime import datetime, timedelta
from typing import Any, Literal

from pydantic import BaseModel, Field
from sqlalchemy import Integer, cast, func, select
from sqlalchemy.ext.asyncio import AsyncSession

from server.facts import prescription_facts
from server.live_audit import TOKEN_SHARED_ACTION
from server.models import AuditEntry, Patient, Prescription, Session, Station, User
from sessions.progress import WEEK, SessionFacts, missed_weeks
from sessions.record import data_missing

LOOKBACK_DAYS = 7
"""Sessions from this many days back are looked at."""
OFFLINE_DAYS = 2
"""A station not seen for this many days (and not connected now) needs a look."""
FAULT_KINDS = ("fault", "estop", "watchdog", "supply_low")
"""Safety events that count as a fault (a range limit reached is the device doing its job)."""

Kind = Literal["fault", "held", "ended_early", "data_missing", "missed", "offline", "token_shared"]


class AttentionItem(BaseModel):
    """One thing to look at."""

    kind: Kind = Field(
        description="fault, held (the exercise was put on hold), ended_early, data_missing "
        "(the session's recording has gaps in its telemetry: its numbers leave them out), missed "
        "(prescribed sessions not done in a prescribed week that ended in the last 7 days, "
        "as the progress page's adherence counts them), offline (a station not seen) or "
        "token_shared (two stations used one station's token in the last 7 days)."
    )
    patient_id: int
    patient_name: str
    at: datetime | None = Field(description="When it happened (a session's start), UTC.")
    text: str = Field(description="What happened, in a sentence.")
    link: str = Field(description="The dashboard page where it happened.")
    session_id: int | None = None
    station_id: int | None = None
    prescription_id: int | None = None


def _patients(user: User) -> Any:
    query = select(Patient.id).where(Patient.archived_at.is_(None))
    return query if user.role == "admin" else query.where(Patient.therapist_id == user.id)


def _session_items(rows: Iterable[Any], names: dict[int, str]) -> Iterable[AttentionItem]:
    for sid, pid, station_id, started, end_reason, summary in rows:
        s: dict[str, Any] = summary or {}
        base = {
            "patient_id": pid,
            "patient_name": names[pid],
            "at": started,
            "link": f"/app/sessions/{sid}",
            "session_id": sid,
            "station_id": station_id,
        }
        faults = [f for f in s.get("faults", []) if f.get("kind") in FAULT_KINDS]
        if faults or end_reason == "fault":
            text = faults[0].get("text") if faults else s.get("end_text")
            more = f" ({len(faults)} in all)" if len(faults) > 1 else ""
            yield AttentionItem(
                kind="fault", text=f"Fault: {text or 'see the session'}{more}.", **base
            )
        holds = int((s.get("events") or {}).get("hold", 0))
        if holds:
            times = "once" if holds == 1 else f"{holds} times"
            yield AttentionItem(kind="held", text=f"The exercise was held {times}.", **base)
        done, prescribed = s.get("repetitions_completed"), s.get("repetitions_prescribed")
        short = isinstance(done, int) and isinstance(prescribed, int) and done < prescribed
        if end_reason in ("stopped", "interrupted") or (end_reason == "completed" and short):
            reps = f": {done} of {prescribed} repetitions" if short else ""
            why = s.get("end_text") or end_reason
            yield AttentionItem(kind="ended_early", text=f"Ended early ({why}){reps}.", **base)
        missing = data_missing(s)
        if missing:
            yield AttentionItem(kind="data_missing", text=f"{missing}.", **base)


OnlineOf = Callable[[list[int]], Awaitable[set[int]]]
"""Which of these stations are connected now (the live hub's ``online_of``)."""


async def attention(
    db: AsyncSession, user: User, now: datetime, online_of: OnlineOf
) -> list[AttentionItem]:
    """What needs ``user``'s attention now: sessions newest first, then missed sessions,
    then stations. A station connected now is never offline, however long ago it was last
    seen."""
    mine = _patients(user)
    query = select(Patient.id, Patient.display_name).where(Patient.id.in_(mine))
    names: dict[int, str] = dict((await db.execute(query)).all())
    since = now - timedelta(days=LOOKBACK_DAYS)
    rows = await db.execute(
        select(
            Session.id,
            Session.patient_id,
            Session.station_id,
            Session.started_at,
            Session.end_reason,
            Session.summary,
        )
        .where(Session.patient_id.in_(mine), Session.started_at >= since)
        .order_by(Session.started_at.desc())
    )
    items = list(_session_items(rows, names))
    items.extend(await _missed(db, mine, names, now))
    items.extend(await _offline(db, mine, names, now, online_of))
    items.extend(await _token_shared(db, mine, names, since))
    return items


async def _missed(
    db: AsyncSession, mine: Any, names: dict[int, str], now: datetime
) -> list[AttentionItem]:
    active = (
        await db.scalars(
            select(Prescription)
            .where(Prescription.patient_id.in_(mine), Prescription.status == "active")
            .order_by(Prescription.id)
        )
    ).all()
    # A prescribed week that ended within the look-back began up to a week before it.
    since = now - timedelta(days=LOOKBACK_DAYS)
    rows = await db.execute(
        select(Session.id, Session.prescription_id, Session.started_at, Session.end_reason).where(
            Session.prescription_id.in_([p.id for p in active]),
            Session.started_at >= since - WEEK,
        )
    )
    sessions = [
        SessionFacts(id=i, prescription_id=rx, started_at=at, end_reason=why, summary=None)
        for i, rx, at, why in rows
    ]
    out: list[AttentionItem] = []
    for row in active:
        rx = prescription_facts(row)
        for w in missed_weeks(rx, sessions, now, since):
            title = rx.title or rx.exercise.value.replace("_", " ")
            early = f", {w.ended_early} ended early" if w.ended_early else ""
            last_day = w.end - timedelta(microseconds=1)
            out.append(
                AttentionItem(
                    kind="missed",
                    patient_id=row.patient_id,
                    patient_name=names[row.patient_id],
                    at=None,
                    text=f"“{title}”: {w.missed} of {w.prescribed} prescribed sessions missed "
                    f"in its week {w.week} ({_day(w.start)} to {_day(last_day)}): "
                    f"{w.completed} done{early}.",
                    link=f"/app/patients/{row.patient_id}",
                    prescription_id=row.id,
                )
            )
    return out


def _day(when: datetime) -> str:
    return f"{when.day} {when:%b}"


async def _offline(
    db: AsyncSession, mine: Any, names: dict[int, str], now: datetime, online_of: OnlineOf
) -> list[AttentionItem]:
    cutoff = now - timedelta(days=OFFLINE_DAYS)
    stations = (
        await db.execute(
            select(
                Station.id,
                Station.patient_id,
                Station.name,
                Station.last_seen_at,
                Station.created_at,
            )
            .where(Station.patient_id.in_(mine), Station.revoked.is_(False))
            .order_by(Station.id)
        )
    ).all()
    quiet = [row[0] for row in stations if (row[3] or row[4]) < cutoff]
    online = await online_of(quiet) if quiet else set()
    out: list[AttentionItem] = []
    for st_id, pid, name, seen, created in stations:
        if st_id in online or (seen or created) >= cutoff:
            continue
        days = (now - (seen or created)).days
        text = (
            f"Station “{name}” has not been seen for {days} days."
            if seen
            else f"Station “{name}” has never connected ({days} days since it was provisioned)."
        )
        out.append(
            AttentionItem(
                kind="offline",
                patient_id=pid,
                patient_name=names[pid],
                at=seen,
                text=text,
                link=f"/app/patients/{pid}",
                station_id=st_id,
            )
        )
    return out


async def _token_shared(
    db: AsyncSession, mine: Any, names: dict[int, str], since: datetime
) -> list[AttentionItem]:
    rows = await db.execute(
        select(Station.id, Station.patient_id, Station.name, func.count(), func.max(AuditEntry.at))
        .join(Station, Station.id == cast(AuditEntry.entity_id, Integer))
        .where(
            AuditEntry.action == TOKEN_SHARED_ACTION,
            AuditEntry.entity == "station",
            AuditEntry.patient_id.in_(mine),
            AuditEntry.at >= since,
        )
        .group_by(Station.id, Station.patient_id, Station.name)
        .order_by(Station.id)
    )
    out: list[AttentionItem] = []
    for st_id, pid, name, count, last in rows:
        times = "once" if count == 1 else f"{count} times"
        out.append(
            AttentionItem(
                kind="token_shared",
                patient_id=pid,
                patient_name=names[pid],
                at=last,
                text=f"Two stations used the token of station “{name}” (recorded {times} in "
                f"the last {LOOKBACK_DAYS} days): the platform seen live may not have been the "
                "patient's; re-provision the station.",
                link=f"/app/patients/{pid}",
                station_id=st_id,
            )
        )
    return out
