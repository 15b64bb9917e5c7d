"""The audit log: who changed what, from which value to which.

``record`` adds the row to the caller's session and does not commit: the row lands in the
same transaction as the change it describes, so there is never a change without its entry
or an entry for a change that was rolled back. Nothing in the API updates or deletes rows.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from sqlalchemy.ext.asyncio import AsyncSession

from server.models import AuditEntry, Station, User

SYSTEM = "system"


def user_actor(user: User) -> str:
    return f"user:{user.id}"


def station_actor(station: Station) -> str:
    return f"station:{station.id}"


def changes(
    before: Mapping[str, Any], after: Mapping[str, Any]
) -> tuple[dict[str, Any], dict[str, Any]]:
    """The fields that differ, as (old, new) dictionaries with the same keys."""
    keys = [k for k in after if before.get(k) != after[k]]
    return {k: before.get(k) for k in keys}, {k: after[k] for k in keys}


def record(
    db: AsyncSession,
    actor: str,
    action: str,
    entity: str,
    entity_id: int | str,
    patient_id: int | None,
    old: Mapping[str, Any] | None,
    new: Mapping[str, Any] | None,
) -> AuditEntry:
    """Add one audit row to ``db``'s current transaction.

    ``actor`` is ``"user:<id>"``, ``"station:<id>"`` or ``"system"``; ``action`` is
    ``"<entity>.<verb>"`` (``"prescription.update"``); ``old`` and ``new`` hold only the
    fields that changed, JSON-serialisable (no secrets: never a password or token hash).
    """
    entry = AuditEntry(
        actor=actor,
        action=action,
        entity=entity,
        entity_id=str(entity_id),
        patient_id=patient_id,
        old=None if old is None else dict(old),
        new=None if new is None else dict(new),
    )
    db.add(entry)
    return entry
