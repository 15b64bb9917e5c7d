"""Each install extra carries what its role runs: the role starts with everything else blocked.

The blocked set is computed, not listed: every installed distribution outside the closure of
the base dependencies and the role's extra (pyproject.toml, followed through each installed
package's own requirements) has its import names refused by a ``sys.meta_path`` finder in a
fresh interpreter, which then starts the role's entry point the way ``ankle`` does.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
import time
import tomllib
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement

from tests.processes import free_port, stop

ROOT = Path(__file__).resolve().parents[1]
PROJECT = "ankle-telerehab"
# In every venv, whatever the project declares: the installer and its import hook.
ALWAYS = {"pip", "setuptools", "_distutils_hack"}


def _canon(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _declared(role: str) -> list[Requirement]:
    """The project's own requirements for ``role``, its self-references expanded."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras: dict[str, list[str]] = project["optional-dependencies"]
    found = [Requirement(r) for r in project["dependencies"]]
    todo, seen = [role], set()
    while todo:
        extra = todo.pop()
        if extra in seen:
            continue
        seen.add(extra)
        for line in extras[extra]:
            req = Requirement(line)
            if _canon(req.name) == PROJECT:
                todo.extend(req.extras)
            else:
                found.append(req)
    return found


def closure(role: str) -> set[str]:
    """Canonical names of every distribution the role's install brings."""
    todo = _declared(role)
    have: dict[str, set[str]] = {}  # name -> the extras already followed
    while todo:
        req = todo.pop()
        name = _canon(req.name)
        wanted = {""} | set(req.extras)
        if name in have and wanted <= have[name]:
            continue
        have.setdefault(name, set()).update(wanted)
        try:
            requires = metadata.distribution(name).requires or []
        except metadata.PackageNotFoundError:
            continue
        for line in requires:
            sub = Requirement(line)
            if sub.marker is None or any(sub.marker.evaluate({"extra": e}) for e in wanted):
                todo.append(sub)
    return set(have)


def blocked_for(role: str) -> set[str]:
    keep = closure(role) | {PROJECT}
    names: set[str] = set()
    for module, dists in metadata.packages_distributions().items():
        if not any(_canon(d) in keep for d in dists):
            names.add(module)
    return names - ALWAYS - {"device", "server", "webui", "sessions", "station", "lab", "ankle"}


PROBE = textwrap.dedent(
    """
    import importlib.abc, sys
    BLOCKED = frozenset(sys.argv[1].split(","))
    class NotInstalled(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"{name} is not installed for this role")
            return None
    sys.meta_path.insert(0, NotInstalled())
    exec(sys.argv[2])
    """
)


def probe(blocked: set[str], code: str, cwd: Path) -> subprocess.Popen[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("ANKLE_")}
    return subprocess.Popen(
        [sys.executable, "-c", PROBE, ",".join(sorted(blocked)), textwrap.dedent(code)],
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def run_probe(blocked: set[str], code: str, cwd: Path, timeout: float = 180.0) -> str:
    proc = probe(blocked, code, cwd)
    out, _ = proc.communicate(timeout=timeout)
    assert proc.returncode == 0, out
    return out


@contextmanager
def serving(proc: subprocess.Popen[str], url: str, deadline_s: float = 120.0) -> Iterator[bytes]:
    """Wait until ``url`` answers, yield its body, then stop the process."""
    try:
        end = time.monotonic() + deadline_s
        while True:
            assert proc.poll() is None, proc.communicate()[0]
            try:
                with urllib.request.urlopen(url, timeout=5) as r:
                    body: bytes = r.read()
                    break
            except OSError:
                if time.monotonic() > end:
                    raise
                time.sleep(0.3)
        yield body
    finally:
        stop(proc)


def test_the_heavy_packages_are_where_they_belong() -> None:
    assert {"matplotlib", "fastapi", "sqlalchemy", "pyarrow"} <= blocked_for("device")
    assert not {"numba", "serial", "cobs"} & blocked_for("device")
    assert {"numba", "matplotlib", "pyarrow", "argon2", "sqlalchemy", "viser"} <= blocked_for(
        "station"
    )
    assert {"numba", "matplotlib"} <= blocked_for("server")
    assert not {"pyarrow", "argon2", "fastapi", "sqlalchemy", "viser"} & blocked_for("server")
    assert not {"numba", "matplotlib", "fastapi"} & blocked_for("lab")


def test_the_blocker_refuses_a_blocked_import(tmp_path: Path) -> None:
    proc = probe({"numba"}, "import numba", tmp_path)
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode != 0 and "numba is not installed for this role" in out


def test_device_runs_without_the_server_station_or_lab(tmp_path: Path) -> None:
    blocked = blocked_for("device")
    assert {"fastapi", "sqlalchemy", "matplotlib", "websockets", "httpx"} <= blocked
    port = free_port()
    out = run_probe(
        blocked,
        f"""
        import sys
        from ankle.cli import main
        code = main(["device", "--sim", "--link", "tcp://127.0.0.1:{port}", "--seconds", "1"])
        sys.exit(code)
        """,
        tmp_path,
    )
    assert "127.0.0.1" in out


def test_station_runs_without_the_server_or_lab(tmp_path: Path) -> None:
    blocked = blocked_for("station")
    # the station's own package does not even need the web framework of its page
    run_probe(
        blocked | {"fastapi", "uvicorn", "starlette"}, "import station.app, station.cli", tmp_path
    )
    page = free_port()
    proc = probe(
        blocked,
        f"""
        import sys
        from ankle.cli import main
        sys.exit(main(["station", "--device", "socket://127.0.0.1:{free_port()}",
            "--server", "http://127.0.0.1:{free_port()}", "--token", "t",
            "--spool", "spool", "--page-port", "{page}"]))
        """,
        tmp_path,
    )
    with serving(proc, f"http://127.0.0.1:{page}/") as body:
        assert b"<html" in body.lower()


def test_server_runs_without_the_device_controller_or_figures(tmp_path: Path) -> None:
    blocked = blocked_for("server")
    assert {"numba", "matplotlib", "serial"} <= blocked
    port = free_port()
    proc = probe(
        blocked,
        f"""
        import sys
        from ankle.cli import main
        sys.exit(main(["server", "--data-dir", "data", "--port", "{port}"]))
        """,
        tmp_path,
    )
    with serving(proc, f"http://127.0.0.1:{port}/api/v1/health") as body:
        assert b'"ok"' in body


@pytest.mark.parametrize("role", ["device", "station", "server"])
def test_ankle_version_in_every_role(role: str, tmp_path: Path) -> None:
    out = run_probe(
        blocked_for(role),
        "from ankle.cli import main; import sys; sys.exit(main(['--version']))",
        tmp_path,
    )
    assert out.strip() == f"ankle {metadata.version(PROJECT)}"
