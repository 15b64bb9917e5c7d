"""The real server on a real port, talked to over HTTP.

A seeded database (an admin, two therapists each with a patient, stations and a
prescription, all made through the API) is built once per test session and store; each test
gets a fresh copy of it in its own ``data_dir`` and its own uvicorn server, so tests never see
each other's changes and no test pays for Argon2 hashing it does not test.

The store is SQLite unless a test (or its module) is marked ``both_stores``: then it runs
twice, on SQLite and on PostgreSQL (a database cloned from a seeded template per test).
"""

from __future__ import annotations

import asyncio
import shutil
import sqlite3
from collections.abc import AsyncIterator, Callable, Coroutine, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import asynccontextmanager, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import httpx
import pytest
import pytest_asyncio
import uvicorn
from fastapi import FastAPI
from sqlalchemy.ext.asyncio import AsyncSession, async_sessionmaker

from server.app import create_app
from server.cli import ensure_user_async
from server.config import Settings
from server.protocols import protocols
from sessions.prescription import EXERCISE_LIBRARY, ExerciseKind
from tests.server.postgres import Cluster

Store = Literal["sqlite", "postgres"]
STORES: tuple[Store, ...] = ("sqlite", "postgres")

PASSWORD = "correct horse battery"
CLIENT_TIMEOUT_S = 60.0
STRENGTH: dict[str, Any] = EXERCISE_LIBRARY[ExerciseKind.STRENGTH].defaults.model_dump(mode="json")


@dataclass
class Live:
    """A running server: its app (for ``app.state``), an HTTP client on ``/api/v1``."""

    app: FastAPI
    client: httpx.AsyncClient
    settings: Settings

    @property
    def sessionmaker(self) -> async_sessionmaker[AsyncSession]:
        maker: async_sessionmaker[AsyncSession] = self.app.state.sessionmaker
        return maker


@asynccontextmanager
async def running(
    settings: Settings, factory: Callable[[Settings], FastAPI] = create_app, port: int = 0
) -> AsyncIterator[Live]:
    """Serve ``factory(settings)`` (the API, or the dashboard that wraps it) with uvicorn on
    ``port`` (a free one if 0) until the block ends, with the server's own protocols
    (``server.protocols``)."""
    app = factory(settings)
    config = uvicorn.Config(
        app, host="127.0.0.1", port=port, lifespan="on", log_level="warning", **protocols(settings)
    )
    server = uvicorn.Server(config)
    task = asyncio.create_task(server.serve())
    while not server.started:
        if task.done():
            raise RuntimeError("the server did not start") from task.exception()
        await asyncio.sleep(0.005)
    port = server.servers[0].sockets[0].getsockname()[1]
    try:
        # httpx's default 5 s read timeout is an idle machine's: a loaded one answers later.
        async with httpx.AsyncClient(
            base_url=f"http://127.0.0.1:{port}/api/v1", timeout=CLIENT_TIMEOUT_S
        ) as client:
            yield Live(app, client, settings)
    finally:
        server.should_exit = True
        await task


def bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


@dataclass(frozen=True)
class World:
    """Who and what the seeded database holds (ids and tokens)."""

    admin: str
    t1: str
    t2: str
    t1_id: int
    t2_id: int
    p1: int
    p2: int
    s1: str
    s1_id: int
    s1_spare_id: int
    s2: str
    s2_id: int
    rx1: int
    rx2: int

    def token(self, role: str) -> str | None:
        """The bearer token of ``anon``, ``admin``, ``t1``, ``t2`` or ``station`` (s1)."""
        return {
            "anon": None,
            "admin": self.admin,
            "t1": self.t1,
            "t2": self.t2,
            "station": self.s1,
        }[role]


async def login(client: httpx.AsyncClient, email: str, password: str = PASSWORD) -> str:
    r = await client.post("/auth/login", json={"email": email, "password": password})
    assert r.status_code == 200, r.text
    token: str = r.json()["access_token"]
    return token


async def _seed(settings: Settings) -> World:
    await ensure_user_async(settings, "admin@clinic.test", "Ada Admin", "admin", PASSWORD)
    async with running(settings) as live:
        c = live.client
        admin = await login(c, "admin@clinic.test")
        ids = {}
        for who in ("t1", "t2"):
            r = await c.post(
                "/users",
                json={
                    "email": f"{who}@clinic.test",
                    "name": who,
                    "role": "therapist",
                    "password": PASSWORD,
                },
                headers=bearer(admin),
            )
            assert r.status_code == 201, r.text
            ids[who] = r.json()["id"]
        t1, t2 = await login(c, "t1@clinic.test"), await login(c, "t2@clinic.test")

        async def post(token: str, path: str, body: dict[str, Any]) -> dict[str, Any]:
            r = await c.post(path, json=body, headers=bearer(token))
            assert r.status_code == 201, r.text
            out: dict[str, Any] = r.json()
            return out

        p1 = await post(t1, "/patients", {"display_name": "Pat One", "affected_side": "left"})
        p2 = await post(t2, "/patients", {"display_name": "Pat Two"})
        s1 = await post(t1, f"/patients/{p1['id']}/stations", {"name": "Home of Pat One"})
        spare = await post(t1, f"/patients/{p1['id']}/stations", {"name": "Spare"})
        s2 = await post(t2, f"/patients/{p2['id']}/stations", {"name": "Home of Pat Two"})
        rx1 = await post(t1, f"/patients/{p1['id']}/prescriptions", STRENGTH)
        rx2 = await post(t2, f"/patients/{p2['id']}/prescriptions", STRENGTH)
    return World(
        admin=admin,
        t1=t1,
        t2=t2,
        t1_id=ids["t1"],
        t2_id=ids["t2"],
        p1=p1["id"],
        p2=p2["id"],
        s1=s1["token"],
        s1_id=s1["id"],
        s1_spare_id=spare["id"],
        s2=s2["token"],
        s2_id=s2["id"],
        rx1=rx1["id"],
        rx2=rx2["id"],
    )


def _run(coroutine: Coroutine[Any, Any, World]) -> World:
    """Run ``coroutine`` to its end from sync code, in a thread of its own if this thread's
    event loop is running (a test asking for a seeded store from inside ``async def``)."""
    try:
        asyncio.get_running_loop()
    except RuntimeError:
        return asyncio.run(coroutine)
    with ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, coroutine).result()


class Seeds:
    """The seeded world of each store, built on first use: a data directory (SQLite) or a
    template database (PostgreSQL)."""

    def __init__(self, tmp: pytest.TempPathFactory, request: pytest.FixtureRequest) -> None:
        self._tmp = tmp
        self._request = request
        self._built: dict[Store, tuple[Path | str, World]] = {}

    @property
    def cluster(self) -> Cluster:
        cluster: Cluster = self._request.getfixturevalue("pg_cluster")
        return cluster

    def get(self, store: Store) -> tuple[Path | str, World]:
        if store not in self._built:
            data_dir = self._tmp.mktemp(f"seeded-{store}")
            if store == "sqlite":
                self._built[store] = (data_dir, _run(_seed(Settings(data_dir=data_dir))))
            else:
                name = self.cluster.create_database()
                settings = Settings(data_dir=data_dir, database_url=self.cluster.url(name))
                self._built[store] = (name, _run(_seed(settings)))
        return self._built[store]


@pytest.fixture(scope="session")
def seeds(tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest) -> Seeds:
    return Seeds(tmp_path_factory, request)


@pytest.fixture
def store(request: pytest.FixtureRequest) -> Store:
    """The store a test runs on: SQLite, or each of both for tests marked ``both_stores``."""
    chosen: Store = getattr(request, "param", "sqlite")
    return chosen


def parametrize_stores(metafunc: pytest.Metafunc) -> None:
    """``pytest_generate_tests`` for the server tests: a test marked ``both_stores`` that
    uses a store runs once per store, unless it is also marked ``sqlite_only`` (it reaches
    into SQLite itself: its file, its PRAGMAs, its trigger syntax)."""
    marked = metafunc.definition.get_closest_marker
    if "store" in metafunc.fixturenames and marked("both_stores") and not marked("sqlite_only"):
        metafunc.parametrize("store", STORES, indirect=True)


@pytest.fixture(scope="session")
def seeded(seeds: Seeds) -> tuple[Path, World]:
    """The seeded SQLite data directory (to copy) and its world."""
    template, world = seeds.get("sqlite")
    assert isinstance(template, Path)
    return template, world


def copy_seeded(template: Path, data_dir: Path) -> Path:
    """A private copy of the seeded database in ``data_dir``."""
    data_dir.mkdir(parents=True, exist_ok=True)
    for f in template.glob("ankle.db*"):
        shutil.copy(f, data_dir / f.name)
    return data_dir


@contextmanager
def on_store(
    seeds: Seeds, store: Store, data_dir: Path, template: Path | str | None = None
) -> Iterator[Settings]:
    """Settings for a private database on ``store``: a copy of ``template`` (the seeded
    world of that store), or empty."""
    if store == "sqlite":
        if isinstance(template, Path):
            copy_seeded(template, data_dir)
        yield Settings(data_dir=data_dir)
        return
    cluster = seeds.cluster
    name = cluster.create_database(template if isinstance(template, str) else None)
    try:
        yield Settings(data_dir=data_dir, database_url=cluster.url(name))
    finally:
        cluster.drop_database(name)


@pytest.fixture
def seeded_store(seeds: Seeds, store: Store) -> tuple[Path | str, World]:
    """The seeded world of the test's store (built here, outside any event loop)."""
    return seeds.get(store)


@pytest_asyncio.fixture
async def live(
    seeds: Seeds, store: Store, seeded_store: tuple[Path | str, World], tmp_path: Path
) -> AsyncIterator[Live]:
    """A server on a private copy of the seeded database."""
    with on_store(seeds, store, tmp_path, seeded_store[0]) as settings:
        async with running(settings) as server:
            yield server


@pytest.fixture
def world(seeded_store: tuple[Path | str, World]) -> World:
    return seeded_store[1]


@pytest.fixture
def fresh(seeds: Seeds, store: Store, tmp_path: Path) -> Iterator[Settings]:
    """Settings for a new, empty database on the test's store."""
    with on_store(seeds, store, tmp_path / "data") as settings:
        yield settings


@pytest_asyncio.fixture
async def empty(seeds: Seeds, store: Store, tmp_path: Path) -> AsyncIterator[Live]:
    """A server on a new, empty data directory (and database)."""
    with on_store(seeds, store, tmp_path) as settings:
        async with running(settings) as server:
            yield server


@asynccontextmanager
async def sqlite_write_locked(path: Path) -> AsyncIterator[None]:
    """Hold an SQLite file's write lock as another client would (a backup, a stuck writer):
    every write waits; reads go on (WAL)."""
    holder = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
    await asyncio.to_thread(holder.execute, "BEGIN EXCLUSIVE")
    try:
        yield
    finally:
        holder.execute("ROLLBACK")
        holder.close()
