"""Entry points for the command line and the one-machine demo: serve, create users, seed.

``ankle server`` (in ``ankle/cli.py``) calls these; each opens and migrates the database by
itself, so they work before the server has ever started.
"""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import time
import urllib.error
import urllib.request
from collections.abc import AsyncIterator, Callable, Iterable
from contextlib import asynccontextmanager
from typing import Any

import uvicorn
from fastapi import FastAPI
from pydantic import ValidationError
from sqlalchemy import select
from sqlalchemy.ext.asyncio import AsyncSession, async_sessionmaker
from uvicorn.config import STARTUP_FAILURE
from uvicorn.supervisors.multiprocess import Multiprocess

from server import accounts, audit
from server.app import create_app
from server.config import Settings
from server.db import create_engine, create_sessionmaker, prepare
from server.logs import uvicorn_log_config
from server.models import Patient, Prescription, Role, Station, User
from server.protocols import protocols
from server.routes import API_PREFIX
from server.routes.stations import revoke
from server.schemas import UserCreate, UserPublic
from server.security import HashingSlots, hash_password, new_password, new_token, token_hash
from sessions.prescription import EXERCISE_LIBRARY, ExerciseKind, PrescriptionBody
from sessions.private import write_private
from sessions.sentences import sentence
from sessions.text import normal_address

DEMO_EMAIL = "therapist@demo.local"
DEMO_THERAPIST_NAME = "Demo Therapist"
DEMO_PATIENT_NAME = "Demo Patient"
DEMO_PATIENT_REFERENCE = "DEMO-1"
DEMO_STATION_NAME = "Demo station"
CREDENTIALS_FILE = "demo-credentials.json"


class ServerStartError(Exception):
    """The server process exited or never answered its health check."""


def wait_healthy(url: str, proc: subprocess.Popen[bytes], timeout: float = 60.0) -> None:
    """Wait until a started server process answers ``/api/v1/health``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise ServerStartError(f"the server exited with code {proc.returncode}")
        try:
            with urllib.request.urlopen(f"{url}/api/v1/health", timeout=1.0) as r:
                if r.status == 200:
                    return
        except (urllib.error.URLError, OSError):
            pass
        time.sleep(0.2)
    raise ServerStartError(f"the server did not answer at {url} within {timeout:g} s")


def serve(
    settings: Settings | None = None,
    factory: Callable[[Settings], FastAPI] = create_app,
    *,
    workers: int = 1,
    worker_factory: str = "server.app:create_app",
) -> None:
    """Run the server in the foreground until Ctrl-C. ``ankle server`` passes the
    dashboard's factory, which wraps this package's.

    With ``workers`` > 1, uvicorn starts that many processes on the one listening socket;
    each builds its app by importing ``worker_factory`` (a factory called with no
    arguments, which reads its settings from ``ANKLE_*`` variables: ``settings`` must be in
    the environment already) and runs its own lifespan: its own engine, migration (under the
    migration lock) and live hub."""
    settings = Settings() if settings is None else settings
    print(
        f"ankle server on {settings.public_url} (API docs: {API_PREFIX}/docs)"
        + (f", {workers} worker processes" if workers > 1 else ""),
        flush=True,
    )
    # No permessage-deflate: compressing every 50 Hz telemetry frame to every viewer (and
    # inflating each station's 100 Hz) cost the live relay about a tenth of its CPU time
    # (``ankle bench server``), for half the bytes of a ~650 B message.
    options: dict[str, Any] = {
        "host": settings.host,
        "port": settings.port,
        "log_level": "info",
        "log_config": uvicorn_log_config(settings.log_format),
        "ws_per_message_deflate": False,
        "timeout_keep_alive": settings.keep_alive_s,
        **protocols(settings),
    }
    if workers > 1:
        _supervise(uvicorn.Config(worker_factory, factory=True, workers=workers, **options))
    else:
        uvicorn.Server(uvicorn.Config(factory(settings), **options)).run()


def _supervise(config: uvicorn.Config) -> None:
    """uvicorn's supervisor of ``config.workers`` processes, as ``uvicorn.run`` starts it;
    ServerStartError when it stopped because one of them failed to start. ``uvicorn.run``
    returns normally then, and ``ankle server --workers`` exited 0 with none serving."""
    supervisor = Multiprocess(config, sockets=[config.bind_socket()])
    supervisor.run()
    failed = [p for p in supervisor.processes if p.exitcode == STARTUP_FAILURE]
    if failed:
        raise ServerStartError(
            f"{len(failed)} of {config.workers} server processes failed to start (the log "
            "above says why); none is serving"
        )


def settings_into_environment(settings: Settings, names: Iterable[str]) -> None:
    """Put the named settings into ``ANKLE_*`` variables, where worker processes (which
    build their own Settings) find them."""
    for name in names:
        os.environ[f"ANKLE_{name.upper()}"] = str(getattr(settings, name))


@asynccontextmanager
async def _database(settings: Settings) -> AsyncIterator[async_sessionmaker[AsyncSession]]:
    engine = create_engine(settings)
    try:
        await prepare(engine, settings.migrate_on_start)
        yield create_sessionmaker(engine)
    finally:
        await engine.dispose()


async def _ensure_user(
    db: AsyncSession, email: str, name: str, role: Role, password: str
) -> tuple[User, bool]:
    valid = UserCreate(email=email, name=name, role=role, password=password)
    user = (await db.execute(select(User).where(User.email == valid.email))).scalar_one_or_none()
    if user is not None:
        return user, False
    user, _ = await accounts.create_user(db, HashingSlots(1), audit.SYSTEM, valid)
    return user, True


async def ensure_user_async(
    settings: Settings, email: str, name: str, role: Role, password: str
) -> bool:
    """Create the account unless one with this email exists (then nothing changes).
    True if it was created. The password is the owner's own: no change is asked of them.
    Raises pydantic's ValidationError for a malformed email or a password ``UserCreate``
    refuses (too short, or too easy to guess: ``server.security.password_weakness``)."""
    async with _database(settings) as sessionmaker, sessionmaker() as db:
        _, created = await _ensure_user(db, email, name, role, password)
        await db.commit()
    return created


def ensure_user(settings: Settings, email: str, name: str, role: Role, password: str) -> bool:
    """``ensure_user_async`` for code outside an event loop (the command line)."""
    return asyncio.run(ensure_user_async(settings, email, name, role, password))


class AdminError(Exception):
    """``ankle admin`` refuses: the one-line message says why (exit 2)."""


OPTION_OF = {"email": "--email", "name": "--name", "role": "--role", "password": "--password-stdin"}
"""The option of ``ankle admin create-user`` that gives each field of ``UserCreate``."""


def _in_words(exc: ValidationError) -> str:
    """The first refusal of a new account, as the API's 422 says it (``sessions.sentences``),
    after the option that gave the value: pydantic's own words quoted the address's regular
    expression."""
    loc, said = sentence(exc.errors()[0], UserCreate)
    option = OPTION_OF.get(str(loc[0])) if loc else None
    return f"{option}: {said}" if option else said


async def create_user_async(
    settings: Settings, email: str, name: str, role: str, password: str | None
) -> tuple[UserPublic, str | None]:
    """``ankle admin create-user``: the new account, and the one-time password the server
    made when none was given (to print once; it must be changed at the first sign-in).
    Raises AdminError for bad input or a taken email."""
    try:
        valid = UserCreate(email=email, name=name, role=role, password=password)  # type: ignore[arg-type]
    except ValidationError as exc:
        raise AdminError(_in_words(exc)) from None
    async with _database(settings) as sessionmaker, sessionmaker() as db:
        try:
            user, one_time = await accounts.create_user(db, HashingSlots(1), audit.SYSTEM, valid)
        except accounts.AccountRefused as exc:
            raise AdminError(f"{exc}: {valid.email}") from None
        await db.commit()
        return UserPublic.model_validate(user), one_time


async def reset_password_async(settings: Settings, email: str) -> tuple[UserPublic, str]:
    """``ankle admin reset-password``: a new one-time password for the account (to print
    once), to be changed at the next sign-in; every login of the account ends (a running
    server closes their live views at its next periodic re-check). Raises AdminError for
    an unknown email."""
    wanted = normal_address(email)
    async with _database(settings) as sessionmaker, sessionmaker() as db:
        user = (await db.execute(select(User).where(User.email == wanted))).scalar_one_or_none()
        if user is None:
            raise AdminError(f"no user has the email {wanted!r}")
        password = await accounts.reset_password(db, HashingSlots(1), audit.SYSTEM, user)
        await db.commit()
        return UserPublic.model_validate(user), password


def demo_prescription() -> PrescriptionBody:
    """The strength exercise's defaults, short enough for a demonstration: 1 set of 3
    repetitions of 6 s."""
    defaults = EXERCISE_LIBRARY[ExerciseKind.STRENGTH].defaults
    return PrescriptionBody.model_validate(
        {**defaults.model_dump(), "sets": 1, "repetitions": 3, "repetition_s": 6.0}
    )


async def _seed_demo(db: AsyncSession) -> dict[str, Any]:
    password = new_password()
    therapist, created = await _ensure_user(
        db, DEMO_EMAIL, DEMO_THERAPIST_NAME, "therapist", password
    )
    if not created:
        # The credentials file is gone, and with it the only copy of the password: the demo
        # account gets a new one rather than being locked out.
        therapist.password_hash = await asyncio.to_thread(hash_password, password)
        therapist.active = True
        therapist.must_change_password = False  # demo credentials work as printed
    patient = (
        await db.execute(
            select(Patient).where(
                Patient.therapist_id == therapist.id,
                Patient.reference == DEMO_PATIENT_REFERENCE,
            )
        )
    ).scalar_one_or_none()
    if patient is None:
        patient = Patient(
            therapist_id=therapist.id,
            display_name=DEMO_PATIENT_NAME,
            reference=DEMO_PATIENT_REFERENCE,
            affected_side="right",
            notes="Created by the demo; not a real person.",
        )
        db.add(patient)
        await db.flush()
        new = {"display_name": patient.display_name, "reference": patient.reference}
        audit.record(
            db, audit.SYSTEM, "patient.create", "patient", patient.id, patient.id, None, new
        )
    # A station token is unrecoverable from its hash: retire any older demo station and
    # provision a fresh one whose token goes into the file.
    old_stations = (
        await db.execute(
            select(Station).where(Station.patient_id == patient.id, Station.revoked.is_(False))
        )
    ).scalars()
    for old in old_stations:
        revoke(db, audit.SYSTEM, old)
    token = new_token()
    station = Station(patient_id=patient.id, name=DEMO_STATION_NAME, token_hash=token_hash(token))
    db.add(station)
    await db.flush()
    audit.record(
        db,
        audit.SYSTEM,
        "station.provision",
        "station",
        station.id,
        patient.id,
        None,
        {"name": station.name, "patient_id": patient.id},
    )
    prescription = (
        await db.execute(
            select(Prescription)
            .where(Prescription.patient_id == patient.id, Prescription.status == "active")
            .order_by(Prescription.id)
        )
    ).scalar()
    if prescription is None:
        body = demo_prescription().model_dump(mode="json")
        prescription = Prescription(patient_id=patient.id, created_by=therapist.id, body=body)
        db.add(prescription)
        await db.flush()
        audit.record(
            db,
            audit.SYSTEM,
            "prescription.create",
            "prescription",
            prescription.id,
            patient.id,
            None,
            {"status": "active", "version": 1, "body": body},
        )
    await db.commit()
    return {
        "therapist_email": therapist.email,
        "therapist_password": password,
        "therapist_id": therapist.id,
        "patient_id": patient.id,
        "patient_name": patient.display_name,
        "station_id": station.id,
        "station_token": token,
        "prescription_id": prescription.id,
    }


async def provision_demo_async(settings: Settings) -> dict[str, Any]:
    """The demo's therapist, patient, station and prescription, created on the first call.

    The credentials (therapist email and password, station token, ids) are written to
    ``data_dir/demo-credentials.json`` (mode 0600) and returned; later calls read that file
    back and change nothing. ``url`` is added from the current settings each time.
    """
    path = settings.data_dir / CREDENTIALS_FILE
    if path.exists():
        credentials: dict[str, Any] = json.loads(path.read_text())
    else:
        async with _database(settings) as sessionmaker, sessionmaker() as db:
            credentials = await _seed_demo(db)
        write_private(path, json.dumps(credentials, indent=2) + "\n")
    return {**credentials, "url": settings.public_url}


def provision_demo(settings: Settings) -> dict[str, Any]:
    """``provision_demo_async`` for code outside an event loop."""
    return asyncio.run(provision_demo_async(settings))
