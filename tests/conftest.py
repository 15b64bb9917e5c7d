"""Shared test settings, and the store fixtures every directory that serves the API uses
(SQLite by default, PostgreSQL too for tests marked ``both_stores``)."""

import ast
import functools
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import settings

from tests.processes import stop
from tests.server.live_server import parametrize_stores, seeded_store, seeds, store
from tests.server.postgres import pg_cluster, pg_url

__all__ = ["pg_cluster", "pg_url", "seeded_store", "seeds", "store"]

# Hundreds of apps start in this one process: none freezes the collector (server/app.py).
# The servers the system tests start as processes freeze it, as deployed (tests/system).
os.environ.setdefault("ANKLE_GC_FREEZE", "false")

# Hypothesis keeps no example database in the tree; CI runs are reproducible from seeds.
settings.register_profile("project", database=None, deadline=None)
settings.load_profile("project")


WARM_TIMEOUT_S = 1800.0
"""A cold compile takes ~2 min on an idle core; a slow, shared CI machine several times that."""

NEEDS_NO_LOOP = (
    *("server/", "sessions/", "station/", "webui/"),
    *("test_dependencies.py", "test_deploy.py", "test_lock.py", "test_wheel.py"),
)
"""Test files and folders (under tests/) that never run the device's compiled loop, in process
or in a service they start: they run while it compiles. Some compile small helpers of their
own (kinematics, the pose check) in seconds. All other tests wait for the compile, and so do
the files here that import one of :data:`LOOP_MODULES`."""

LOOP_MODULES = (
    *("device.controller", "device.hardware", "device.process", "device.rig"),
    *("device.service", "device.tickloop", "tests.device.service_thread"),
)
"""Modules that run (or start a service that runs) the compiled loop. A file in
:data:`NEEDS_NO_LOOP`'s folders that imports one waits for the compile like the rest: cold,
``station/test_stop.py`` (a service in a thread) compiled the loop itself beside the
background compile, and took one of three workers for 500 s."""

_WARM_ENV = "ANKLE_TEST_WARM_DIR"
_warm: subprocess.Popen[bytes] | None = None


@functools.cache
def _imports_loop(path: Path) -> bool:
    """Whether the test file ``path`` imports one of :data:`LOOP_MODULES` (or from them)."""
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module is not None:
            names = [node.module, *(f"{node.module}.{alias.name}" for alias in node.names)]
        else:
            continue
        if any(n == m or n.startswith(m + ".") for n in names for m in LOOP_MODULES):
            return True
    return False


def _needs_loop(path: Path) -> bool:
    name = path.resolve().relative_to(Path(__file__).resolve().parent).as_posix()
    return not name.startswith(NEEDS_NO_LOOP) or _imports_loop(path)


HARDWARE_WARM = """
from device import tickloop
from device.rig import Rig

rig = Rig()
tickloop.HardwareLoop(rig.state, rig.params)
"""
"""Compiles the Python hardware loop's entries (:class:`device.tickloop.HardwareLoop`: the
controller's tick called alone, not inlined in the simulation's loop): a minute of a cold
compile's CPU that the first test to need it (:data:`HARDWARE_LOOP_NAMES`) spent waiting."""

HARDWARE_LOOP_NAMES = frozenset({"HardwareLoop", "run_hardware", "controller_tick", "Hardware"})
"""Names whose use in a test file means it runs the hardware loop: the loop itself, the
controller's tick called from Python, or a hardware of its own (a subclass of ``Hardware``).
Such a file waits for :data:`HARDWARE_WARM` too."""


def pytest_sessionstart(session: pytest.Session) -> None:
    """Start compiling the device's loops once, before any worker starts (this runs ahead of
    xdist's own hook, which starts the workers, and they inherit the folder's name).

    Cold, every worker and every device service a test starts would compile the same code at
    the same time: on two busy cores that took one service past its start deadline. So the
    compile runs once, in the background: the tests that need no compiled loop run meanwhile
    (they come first: ``pytest_collection_modifyitems``), and each other test waits for it
    (``pytest_runtest_setup``), then loads the cache in about a second. Waiting instead, as
    before, left one of two cores idle for the two minutes of a cold compile.

    The simulated service compiles first (most tests wait for it), then the hardware loop
    (:data:`HARDWARE_WARM`), one after the other: two compiles at once would take CPU from
    the tests running meanwhile and delay the one most tests wait for."""
    global _warm
    if _WARM_ENV in os.environ:  # a worker: the controller has started it
        return
    folder = Path(tempfile.mkdtemp(prefix="ankle-warm-"))
    os.environ[_WARM_ENV] = str(folder)
    argv = [sys.executable, "-m", "device", "device", "--sim", "--link", "tcp://127.0.0.1:0"]

    def spawn(args: list[str], log_name: str) -> subprocess.Popen[bytes]:
        global _warm
        with (folder / log_name).open("wb") as log:
            _warm = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT)
        return _warm

    def done(name: str, code: int) -> None:
        (folder / f"{name}.tmp").write_text(str(code))
        (folder / f"{name}.tmp").replace(folder / name)

    def report(proc: subprocess.Popen[bytes]) -> None:
        code = proc.wait()
        done("exit", code)
        if code != 0:
            done("hw-exit", code)
            return
        done("hw-exit", spawn([sys.executable, "-c", HARDWARE_WARM], "hw-log").wait())

    first = spawn([*argv, "--seconds", "0"], "log")
    threading.Thread(target=report, args=(first,), daemon=True).start()


def pytest_sessionfinish(session: pytest.Session) -> None:
    if _warm is None:
        return
    stop(_warm)
    shutil.rmtree(os.environ.pop(_WARM_ENV), ignore_errors=True)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Files in the order xdist hands them out (the Makefile turns off its own order, by
    number of tests, which sent the few long browser files last, together):

    - the files that need no compiled loop, so both workers have work while it compiles;
    - then the long files first (system, the command line, the lab) and the device's many
      short ones last, so that no long file is left running alone at the end;
    - the browser files spread evenly among those. A browser test takes most of two cores
      (chromium draws the pages and the 3D view in software, beside the whole system), and
      a page draws for as long as it is open: two at once each took longer, and more CPU."""
    files: dict[Path, list[pytest.Item]] = {}
    for item in items:
        files.setdefault(item.path, []).append(item)  # a file's tests keep their order

    def rank(path: Path) -> int:
        if path.parent.name == "system":
            return 0
        return 1 if path.name == "test_cli.py" or path.parent.name == "lab" else 2

    first = [f for f in files if not _needs_loop(f)]
    browser = [f for f in files if _needs_loop(f) and f.parent.name == "browser"]
    rest = sorted((f for f in files if _needs_loop(f) and f not in browser), key=rank)
    every = max(1, len(rest) // max(1, len(browser)))
    order = list(first)
    for i, f in enumerate(rest):
        if i % every == 0 and browser:
            order.append(browser.pop(0))
        order.append(f)
    order += browser
    items[:] = [item for f in order for item in files[f]]


@functools.cache
def _uses_hardware_loop(path: Path) -> bool:
    """Whether the test file ``path`` names one of :data:`HARDWARE_LOOP_NAMES`."""
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Name) and node.id in HARDWARE_LOOP_NAMES:
            return True
        if isinstance(node, ast.Attribute) and node.attr in HARDWARE_LOOP_NAMES:
            return True
    return False


def _wait_for(folder: Path, name: str, log_name: str, what: str) -> None:
    """Wait until the warm-up step that writes ``name`` has ended; fail unless it exited 0."""
    deadline = time.monotonic() + WARM_TIMEOUT_S
    while not (folder / name).exists():
        if time.monotonic() > deadline:
            pytest.fail(f"{what} did not compile in {WARM_TIMEOUT_S:.0f} s")
        time.sleep(0.2)
    code = (folder / name).read_text()
    if code != "0":
        pytest.fail(
            f"{what} does not start (exit {code}):\n"
            + (folder / log_name).read_text(errors="replace")[-8000:],
            pytrace=False,
        )


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    """A test that runs the compiled loop waits, before its fixtures, for the compile."""
    folder = Path(os.environ[_WARM_ENV])
    if not _needs_loop(item.path):
        return
    if not (folder / "ok").exists():
        _wait_for(folder, "exit", "log", "the device service")
        (folder / "ok").touch()
    if _uses_hardware_loop(item.path) and not (folder / "hw-ok").exists():
        _wait_for(folder, "hw-exit", "hw-log", "the hardware loop")
        (folder / "hw-ok").touch()


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    parametrize_stores(metafunc)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    """A failed test that ran the whole system shows the tail of every process's log (the
    servers', the station's): a test that failed on a loaded machine is then diagnosable
    from its report, after pytest has removed its temporary folder."""
    outcome = yield
    report = outcome.get_result()  # type: ignore[attr-defined]
    system = getattr(item, "funcargs", {}).get("system")
    if report.failed and system is not None and hasattr(system, "log_tail"):
        report.sections.append(("system logs", system.log_tail()))
