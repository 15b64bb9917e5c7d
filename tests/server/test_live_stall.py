"""A database that does not answer never holds a HOLD back.

A K/B change, Resume or Start is sent only once its request row is committed; a HOLD or
Stop never waits for the database. The live link handled one command at a time, so a HOLD
read after a K/B change waited for the K/B change's row: behind a locked SQLite file the
device held 4.85 s late, and behind a stalled PostgreSQL only once it answered, the K change
then applied 12 s after it was asked. Now a HOLD goes out at once whatever waits, a command
that waits is refused (AUDIT) within ``AUDIT_WAIT_S`` of its arrival and never sent later,
and one that was recorded while a HOLD went out is not sent after it (SUPERSEDED).

Another client holds the table (SQLite: its write lock, so a write waits out the busy timeout;
PostgreSQL: ``LOCK TABLE``, so a statement waits for as long as it is held, as on a stalled
server); a real server, and a raw station that answers as a station relays its device.
"""

from __future__ import annotations

import asyncio
import signal
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import text

from server import hub
from server.config import Settings
from server.hub import (
    AUDIT_WAIT_S,
    BUSY,
    COMMAND_BURST,
    COMMANDS_PER_S,
    NOT_RECORDED_IN_TIME,
    SUPERSEDED,
    UNCHECKED,
    VIEW_COMMANDS_MAX,
)
from sessions import wire
from tests.server.live_server import (
    Live,
    Store,
    World,
    copy_seeded,
    running,
    sqlite_write_locked,
)
from tests.server.redis_server import spawned_redis
from tests.server.test_live_audit import (
    WAIT_S,
    Station,
    Viewer,
    ack,
    audit_rows,
    station,
    vector,
    viewer,
)

pytestmark = pytest.mark.both_stores


@asynccontextmanager
async def held(live: Live, store: Store, table: str) -> AsyncIterator[None]:
    """Hold ``table`` as another client would (a backup, a migration, a stuck writer): on
    SQLite the whole file's write lock (reads go on: WAL), on PostgreSQL the table, so that
    even reads of it wait."""
    if store == "sqlite":
        async with sqlite_write_locked(live.settings.data_dir / "ankle.db"):
            yield
        return
    async with live.sessionmaker() as db:
        await db.execute(text(f"LOCK TABLE {table} IN ACCESS EXCLUSIVE MODE"))
        try:
            yield
        finally:
            await db.rollback()


async def relayed(link: Station, request_id: str) -> wire.Command:
    """The next command the station is sent, which must be ``request_id``."""
    cmd = await link.next_command()
    assert cmd.request_id == request_id, f"{cmd.request_id} reached the station, not {request_id}"
    return cmd


async def answers(v: Viewer, *request_ids: str) -> list[wire.CommandResult]:
    """The results of these commands, in the order they came."""
    deadline = time.monotonic() + WAIT_S
    got: list[wire.CommandResult] = []
    while len(got) < len(request_ids):
        left = deadline - time.monotonic()
        assert left > 0, f"answered within {WAIT_S} s: {[r.request_id for r in got]}"
        message = wire.VIEWER_DOWN.validate_json(await asyncio.wait_for(v.ws.recv(), left))
        if isinstance(message, wire.CommandResult) and message.request_id in request_ids:
            got.append(message)
    return got


async def outcome(live: Live, world: World, request_id: str) -> list[dict[str, Any]]:
    """A command's audit rows, oldest first, once its outcome (the newest) is stored."""
    deadline = time.monotonic() + WAIT_S
    while True:
        rows = await audit_rows(live, world.admin, request_id=request_id)
        if rows and not rows[0]["action"].endswith(".request"):
            return rows[::-1]
        assert time.monotonic() < deadline, f"{request_id}: no outcome row within {WAIT_S} s"
        await asyncio.sleep(0.05)


async def nothing_more(link: Station, v: Viewer) -> None:
    """Nothing else reaches the station, even once the database answers again: a
    heartbeat's round trip through the server, then a command sent after, go first."""
    await v.send("after", "hold")
    assert (await v.next_of(wire.CommandResult, "after")).ok
    cmd = await link.next_command()
    assert cmd.request_id == "after", f"{cmd.request_id} reached the station late"


@pytest.mark.asyncio
async def test_a_hold_goes_out_while_a_kb_change_waits_for_the_database(
    live: Live, world: World, store: Store
) -> None:
    """The therapist changes K, the database does not take its row, and 0.2 s later presses
    HOLD: the HOLD reaches the station, and is answered, while the database is still held
    and before the K/B change is; the K/B change is refused (AUDIT) and never sent."""
    async with (
        station(live, world, ack, stiffness=vector(pitch=40.0)) as link,
        viewer(live, world.t1, world.s1_id) as v,
    ):
        await v.next_of(wire.TelemetryBatch)
        async with held(live, store, "audit_log"):
            await v.send("kb", "set_impedance", stiffness={"pitch": 55.0})
            await asyncio.sleep(0.2)
            await v.send("hold", "hold")
            await relayed(link, "hold")
            hold, kb = await answers(v, "hold", "kb")
        assert (hold.request_id, hold.ok) == ("hold", True), "the K/B change was answered first"
        assert (kb.ok, kb.code, kb.text) == (False, "AUDIT", NOT_RECORDED_IN_TIME)
        assert f"within {AUDIT_WAIT_S:g} s" in kb.text
        await nothing_more(link, v)
    rows = await outcome(live, world, "kb")
    # A row the database took late (the statement it was waiting on) is followed by the
    # refusal that says the change was never sent.
    assert (rows[-1]["action"], rows[-1]["new"]["code"]) == ("impedance.refused", "AUDIT")
    assert [r["action"] for r in rows[:-1]] in ([], ["impedance.request"])
    assert await audit_rows(live, world.admin, action="impedance.change") == []
    hold_rows = await outcome(live, world, "hold")
    assert [r["action"] for r in hold_rows] == ["hold.request", "hold.accepted"]


@pytest.mark.asyncio
async def test_a_resume_recorded_after_a_hold_went_out_is_not_sent_after_it(
    live: Live, world: World, store: Store, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Resume, then HOLD while the Resume's row waits: the HOLD goes out first. When the
    database takes the Resume's row, in time, the Resume is still not sent: sent after the
    HOLD, it would have undone it and moved the platform again."""
    monkeypatch.setattr(hub, "AUDIT_WAIT_S", WAIT_S)  # the database answers in time
    async with (
        station(live, world, ack) as link,
        viewer(live, world.t1, world.s1_id) as v,
    ):
        async with held(live, store, "audit_log"):
            await v.send("resume", "resume")
            await asyncio.sleep(0.2)
            await v.send("hold", "hold")
            await relayed(link, "hold")
        result = await v.next_of(wire.CommandResult, "resume")
        assert (result.ok, result.code, result.text) == (False, "SUPERSEDED", SUPERSEDED)
        await nothing_more(link, v)
    resume = await outcome(live, world, "resume")
    assert [(r["action"], r["new"].get("code")) for r in resume] == [
        ("resume.request", None),
        ("resume.refused", "SUPERSEDED"),
    ]


@pytest.mark.asyncio
async def test_a_start_whose_prescription_cannot_be_checked_in_time_is_refused(
    live: Live, world: World, store: Store
) -> None:
    """A Start waits for its prescription to be checked and its row to be committed, within
    AUDIT_WAIT_S of its arrival; then it is refused, and it never starts later."""
    table = "audit_log" if store == "sqlite" else "prescriptions"  # SQLite's reads go on
    async with (
        station(live, world, ack) as link,
        viewer(live, world.t1, world.s1_id) as v,
    ):
        async with held(live, store, table):
            t0 = time.monotonic()
            await v.send("start", "start", prescription_id=world.rx1)
            result = await v.next_of(wire.CommandResult, "start")
            waited = time.monotonic() - t0
            assert (result.ok, result.code) == (False, "AUDIT")
            assert result.text == (UNCHECKED if table == "prescriptions" else NOT_RECORDED_IN_TIME)
            assert waited >= AUDIT_WAIT_S - 0.1
        await nothing_more(link, v)
    rows = await outcome(live, world, "start")
    assert (rows[-1]["action"], rows[-1]["new"]["code"]) == ("start.refused", "AUDIT")
    assert [r["action"] for r in rows[:-1]] in ([], ["start.request"])


@pytest.mark.asyncio
async def test_each_answer_keeps_its_request_id_when_commands_end_out_of_order(
    live: Live, world: World, store: Store
) -> None:
    """K/B changes wait their turn, in the order asked, while a HOLD and a Stop pass them:
    those two are sent and answered first, and every asker is answered for its own
    request_id."""
    asked: list[tuple[str, str, dict[str, Any]]] = [
        ("kb-1", "set_impedance", {"stiffness": {"pitch": 50.0}}),
        ("kb-2", "set_impedance", {"damping": {"pitch": 3.0}}),
        ("hold-1", "hold", {}),
        ("stop-1", "stop", {}),
    ]
    async with (
        station(live, world, ack, stiffness=vector(pitch=40.0)) as link,
        viewer(live, world.t1, world.s1_id) as v,
    ):
        async with held(live, store, "audit_log"):
            for request_id, action, fields in asked:
                await v.send(request_id, action, **fields)
            assert [(await link.next_command()).request_id for _ in range(2)] == [
                "hold-1",
                "stop-1",
            ]
            came = await answers(v, *(rid for rid, _, _ in asked))
        await nothing_more(link, v)
    order = [r.request_id for r in came]
    assert order[:2] == ["hold-1", "stop-1"], order
    assert sorted(order[2:]) == ["kb-1", "kb-2"], order
    by_id = {r.request_id: r for r in came}
    assert by_id["hold-1"].ok and by_id["stop-1"].ok
    for rid in ("kb-1", "kb-2"):
        assert (by_id[rid].ok, by_id[rid].code) == (False, "AUDIT"), by_id[rid]


@pytest.mark.asyncio
async def test_a_view_has_at_most_so_many_commands_in_hand_at_once(
    seeded: tuple[Path, World], tmp_path: Path
) -> None:
    """Each command is a task of its own: a view within its command budget, whose commands
    cannot end (the relay that says where its station is does not answer), is refused past
    VIEW_COMMANDS_MAX (BUSY), rather than given ever more tasks; each command still gets its
    one answer once the relay is back. K/B changes: a HOLD waits for the relay only
    ``SAFE_OWNER_WAIT_S`` and is refused, so HOLDs never pile up."""
    world = seeded[1]
    data_dir = copy_seeded(seeded[0], tmp_path / "data")
    (tmp_path / "redis").mkdir()
    with spawned_redis(tmp_path / "redis") as (proc, url):
        relayed = Settings(data_dir=data_dir, relay_url=f"{url}/0")
        async with running(relayed) as a, viewer(a, world.t1, world.s1_id) as v:
            asked = [f"kb-{n}" for n in range(VIEW_COMMANDS_MAX + 1)]
            proc.send_signal(signal.SIGSTOP)  # Redis stands still: no answer, no error
            try:
                # The budget's whole burst at once, then one more as soon as the window lets
                # it: all of it well inside the 5 s the relay's look-ups wait for Redis.
                for request_id in asked[:-1]:
                    await v.send(request_id, "set_impedance", stiffness={"pitch": 50.0})
                await asyncio.sleep(COMMAND_BURST / COMMANDS_PER_S + 0.05)
                await v.send(asked[-1], "set_impedance", stiffness={"pitch": 50.0})
                busy = await v.next_of(wire.CommandResult, asked[-1])
            finally:
                proc.send_signal(signal.SIGCONT)
            assert (busy.ok, busy.code, busy.text) == (False, "BUSY", BUSY)
            came = await answers(v, *asked[:-1])
    assert sorted(r.request_id for r in came) == sorted(asked[:-1])
    assert {r.code for r in came} == {"OFFLINE"}, came  # the station is not connected
