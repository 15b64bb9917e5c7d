"""The server's tables, as SQLAlchemy 2 typed ORM classes.

The schema itself is owned by the Alembic migrations in ``server/migrations``; a test checks
that they and these classes agree. Times are timezone-aware UTC on the Python side whatever
the database does with them (SQLite stores no offset).
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any, ClassVar, Literal

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    CheckConstraint,
    DateTime,
    Dialect,
    Float,
    ForeignKey,
    Integer,
    MetaData,
    String,
    Text,
    TypeDecorator,
    false,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

from sessions import recording

Role = Literal["therapist", "admin"]
ROLES: tuple[Role, ...] = ("therapist", "admin")
Side = Literal["left", "right", "both"]
SIDES: tuple[Side, ...] = ("left", "right", "both")
PrescriptionStatus = Literal["active", "cancelled", "completed"]
PRESCRIPTION_STATUSES: tuple[PrescriptionStatus, ...] = ("active", "cancelled", "completed")

# Named constraints so that migrations can refer to them (SQLite batch mode needs names).
NAMING = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}


ID = BigInteger().with_variant(Integer(), "sqlite")
"""Every id and every column naming one: 64-bit on PostgreSQL (migration 0003), and
SQLite's INTEGER, whose primary key is already a 64-bit rowid that autoincrements."""
ID_MAX = recording.ID_MAX
"""The largest id the store holds; the API refuses any outside 1..ID_MAX (``server.deps.Id``),
as do the live links (``sessions.wire.Id``) and uploads (``sessions.recording.Header``)."""


def utcnow() -> datetime:
    return datetime.now(UTC)


class UTCDateTime(TypeDecorator[datetime]):
    """A timezone-aware UTC datetime in and out, stored as naive UTC where the database
    keeps no offset (SQLite), so that SQL comparisons of stored times stay correct."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            raise ValueError("naive datetime given to a UTC column; use datetime.now(UTC)")
        value = value.astimezone(UTC)
        return value.replace(tzinfo=None) if dialect.name == "sqlite" else value

    def process_result_value(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING)
    type_annotation_map: ClassVar[dict[Any, Any]] = {
        datetime: UTCDateTime(),
        dict[str, Any]: JSON(),
    }


class User(Base):
    """A therapist or an administrator: someone who logs in to the dashboard."""

    __tablename__ = "users"
    __table_args__ = (CheckConstraint("role IN ('therapist', 'admin')", name="role"),)

    id: Mapped[int] = mapped_column(ID, primary_key=True)
    email: Mapped[str] = mapped_column(String(254), unique=True)
    name: Mapped[str] = mapped_column(String(120))
    role: Mapped[str] = mapped_column(String(16))
    password_hash: Mapped[str] = mapped_column(String(255))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    active: Mapped[bool] = mapped_column(Boolean, default=True)
    must_change_password: Mapped[bool] = mapped_column(
        Boolean, default=False, server_default=false()
    )
    """The password was printed or reset (someone else has seen it): until its owner
    chooses a new one, their logins may only change it (``server.deps``)."""


class AuthToken(Base):
    """A login: only the SHA-256 of the bearer token is kept, so a leaked database gives
    nobody a usable token."""

    __tablename__ = "auth_tokens"

    id: Mapped[int] = mapped_column(ID, primary_key=True)
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    user_id: Mapped[int] = mapped_column(ID, ForeignKey("users.id"), index=True)
    expires_at: Mapped[datetime]
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Patient(Base):
    """A patient, under the care of one therapist (the tenant boundary of the API)."""

    __tablename__ = "patients"
    __table_args__ = (
        CheckConstraint("affected_side IN ('left', 'right', 'both')", name="affected_side"),
    )

    id: Mapped[int] = mapped_column(ID, primary_key=True)
    therapist_id: Mapped[int] = mapped_column(ID, ForeignKey("users.id"), index=True)
    display_name: Mapped[str] = mapped_column(String(120))
    reference: Mapped[str | None] = mapped_column(String(64))
    birth_year: Mapped[int | None] = mapped_column(Integer)
    affected_side: Mapped[str | None] = mapped_column(String(8))
    weight_kg: Mapped[float | None] = mapped_column(Float)
    """Body weight, kg (migration 0004): torque is also shown per kilogram where known."""
    notes: Mapped[str] = mapped_column(Text, default="")
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)
    archived_at: Mapped[datetime | None]
    """When the therapist archived the patient (treatment ended): the record is read-only
    and left out of the default patient list. None for a current patient."""


class Station(Base):
    """A patient's home station, known by the hash of the token it was provisioned with."""

    __tablename__ = "stations"

    id: Mapped[int] = mapped_column(ID, primary_key=True)
    patient_id: Mapped[int] = mapped_column(ID, ForeignKey("patients.id"), index=True)
    name: Mapped[str] = mapped_column(String(120))
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    last_seen_at: Mapped[datetime | None]
    revoked: Mapped[bool] = mapped_column(Boolean, default=False)


class Prescription(Base):
    """A ``sessions.prescription.PrescriptionBody`` for one patient, versioned on each edit."""

    __tablename__ = "prescriptions"
    __table_args__ = (
        CheckConstraint("status IN ('active', 'cancelled', 'completed')", name="status"),
    )

    id: Mapped[int] = mapped_column(ID, primary_key=True)
    patient_id: Mapped[int] = mapped_column(ID, ForeignKey("patients.id"), index=True)
    created_by: Mapped[int] = mapped_column(ID, ForeignKey("users.id"))
    body: Mapped[dict[str, Any]]
    status: Mapped[str] = mapped_column(String(16), default="active")
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)
    version: Mapped[int] = mapped_column(Integer, default=1)


class Session(Base):
    """One recorded run of a prescription, as uploaded by a station."""

    __tablename__ = "sessions"

    id: Mapped[int] = mapped_column(ID, primary_key=True)
    session_uuid: Mapped[str] = mapped_column(String(36), unique=True)
    station_id: Mapped[int] = mapped_column(ID, ForeignKey("stations.id"), index=True)
    patient_id: Mapped[int] = mapped_column(ID, ForeignKey("patients.id"), index=True)
    prescription_id: Mapped[int | None] = mapped_column(ID, ForeignKey("prescriptions.id"))
    started_at: Mapped[datetime]
    ended_at: Mapped[datetime | None]
    end_reason: Mapped[str | None] = mapped_column(String(64))
    size_bytes: Mapped[int] = mapped_column(BigInteger, default=0)
    sha256: Mapped[str | None] = mapped_column(String(64))
    summary: Mapped[dict[str, Any] | None]
    file_path: Mapped[str | None] = mapped_column(String(500))
    upload_complete: Mapped[bool] = mapped_column(Boolean, default=False)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Upload(Base):
    """A resumable upload in progress: how many bytes of a session file have arrived."""

    __tablename__ = "uploads"

    session_uuid: Mapped[str] = mapped_column(String(36), primary_key=True)
    station_id: Mapped[int] = mapped_column(ID, ForeignKey("stations.id"), index=True)
    received_bytes: Mapped[int] = mapped_column(BigInteger, default=0)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)


class AuditEntry(Base):
    """Who changed what, when, from which value to which. Append-only: triggers refuse UPDATE
    and DELETE (and TRUNCATE on PostgreSQL), whatever the application asks."""

    __tablename__ = "audit_log"

    id: Mapped[int] = mapped_column(ID, primary_key=True)
    at: Mapped[datetime] = mapped_column(default=utcnow, index=True)
    actor: Mapped[str] = mapped_column(String(64))
    action: Mapped[str] = mapped_column(String(64), index=True)
    entity: Mapped[str] = mapped_column(String(32))
    entity_id: Mapped[str] = mapped_column(String(64))
    patient_id: Mapped[int | None] = mapped_column(ID, ForeignKey("patients.id"), index=True)
    old: Mapped[dict[str, Any] | None]
    new: Mapped[dict[str, Any] | None]


class IdempotencyKey(Base):
    """A create sent with an ``Idempotency-Key`` (``server.idempotency``): what the same
    request sent again by the same user with the same key is answered, for a day."""

    __tablename__ = "idempotency_keys"

    user_id: Mapped[int] = mapped_column(ID, ForeignKey("users.id"), primary_key=True)
    key: Mapped[str] = mapped_column(String(128), primary_key=True)
    request_sha256: Mapped[str] = mapped_column(String(64))
    """Of the method, the path and the body as validated: the same key with another
    request is refused, never answered with this one's answer."""
    status: Mapped[int] = mapped_column(Integer)
    answer: Mapped[dict[str, Any]]
    created_at: Mapped[datetime] = mapped_column(default=utcnow, index=True)
