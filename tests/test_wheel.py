"""The built wheel installs and serves the whole server outside the repository.

The wheel is built from a copy of the source (what git tracks, plus the npm libraries that
``make setup`` installed), installed with ``--no-deps`` into a fresh venv in a temporary
folder; that venv reaches the project venv's third-party packages through a ``.pth`` line
(never its editable install of this project). ``ankle server`` then runs from that venv with
its working directory outside the repository.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from tests.processes import free_port, stop

ROOT = Path(__file__).resolve().parents[1]
PASSWORD = "a wheel-installed passphrase"


def _sh(*args: str | Path, cwd: Path, env: dict[str, str], stdin: str | None = None) -> str:
    done = subprocess.run(
        [str(a) for a in args],
        cwd=cwd,
        env=env,
        input=stdin,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, f"{args}\n{done.stdout}\n{done.stderr}"
    return done.stdout


def _clean_env() -> dict[str, str]:
    drop = ("ANKLE_", "PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")
    return {k: v for k, v in os.environ.items() if not k.startswith(drop)}


def _source_copy(dest: Path) -> None:
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
        capture_output=True,
        check=True,
    ).stdout.decode()
    for rel in filter(None, listed.split("\0")):
        src = ROOT / rel
        if src.is_file():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)
    modules = ROOT / "webui" / "node_modules"
    if modules.is_dir():
        shutil.copytree(modules, dest / "webui" / "node_modules")


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The venv the wheel was installed into."""
    base = tmp_path_factory.mktemp("wheel")
    assert not base.resolve().is_relative_to(ROOT)
    env = _clean_env()
    src, dist, venv = base / "src", base / "dist", base / "venv"
    _source_copy(src)
    pip = (sys.executable, "-m", "pip")
    _sh(*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", dist, src, cwd=base, env=env)
    (wheel,) = dist.glob("ankle_telerehab-*.whl")
    _sh(sys.executable, "-m", "venv", "--without-pip", venv, cwd=base, env=env)
    python = venv / "bin" / "python"
    site = Path(
        _sh(
            python,
            "-c",
            "import sysconfig; print(sysconfig.get_path('purelib'))",
            cwd=base,
            env=env,
        ).strip()
    )
    (site / "project-deps.pth").write_text(sysconfig.get_path("purelib") + "\n")
    _sh(*pip, "--python", python, "install", "--no-deps", "--no-index", wheel, cwd=base, env=env)
    return venv


def test_the_modules_come_from_the_wheel(installed: Path) -> None:
    out = _sh(
        installed / "bin" / "python",
        "-c",
        "import json, ankle, device, server, station, webui, sessions, lab, webui.assets as a;"
        "import webui.home.app as h;"
        "print(json.dumps({'files': [m.__file__ for m in (ankle, device, server, station, "
        "webui, sessions, lab)], 'missing': a.missing_vendor(),"
        "'home': [n for n in (h.PAGE, *h.FILES) if not (h.STATIC / n).is_file()]}))",
        cwd=installed.parent,
        env=_clean_env(),
    )
    found = json.loads(out)
    for file in found["files"]:
        assert Path(file).resolve().is_relative_to(installed.resolve()), file
    if (ROOT / "webui" / "node_modules").is_dir():  # built after make setup: libraries inside
        assert found["missing"] == []
    assert found["home"] == [], "the patient's page is missing files"


def _get(url: str, data: dict[str, str] | None = None) -> tuple[int, bytes, str]:
    body = None if data is None else json.dumps(data).encode()
    request = urllib.request.Request(url, data=body, headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(request, timeout=10) as r:
            return r.status, r.read(), r.headers.get("Content-Type", "")
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read(), exc.headers.get("Content-Type", "")


def test_the_installed_server_serves_pages_scripts_health_and_sign_in(
    installed: Path, tmp_path: Path
) -> None:
    ankle = installed / "bin" / "ankle"
    env = _clean_env()
    run = tmp_path / "run"
    run.mkdir()
    assert _sh(ankle, "--version", cwd=run, env=env).strip().startswith("ankle ")
    _sh(
        ankle,
        "admin",
        "create-user",
        "--email",
        "admin@clinic.test",
        "--name",
        "Admin",
        "--role",
        "admin",
        "--password-stdin",
        "--data-dir",
        "data",
        cwd=run,
        env=env,
        stdin=PASSWORD + "\n",
    )
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    proc = subprocess.Popen(
        [ankle, "server", "--data-dir", "data", "--port", str(port)],
        cwd=run,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        deadline = time.monotonic() + 120
        while True:
            assert proc.poll() is None, proc.communicate()[0]
            try:
                status, body, _ = _get(f"{base}/api/v1/health")
                break
            except OSError:
                assert time.monotonic() < deadline, "the installed server never answered"
                time.sleep(0.3)
        assert status == 200 and json.loads(body)["status"] == "ok"
        status, body, kind = _get(f"{base}/app/login")
        assert status == 200 and kind.startswith("text/html") and b"<html" in body.lower()
        status, body, kind = _get(f"{base}/static/js/api.js")
        assert status == 200 and "javascript" in kind and len(body) > 100
        if (ROOT / "webui" / "node_modules").is_dir():
            status, body, _ = _get(f"{base}/vendor/uPlot.iife.min.js")
            assert status == 200 and b"uPlot" in body
        status, body, _ = _get(
            f"{base}/api/v1/auth/login", {"email": "admin@clinic.test", "password": PASSWORD}
        )
        assert status == 200 and json.loads(body)["access_token"]
        status, body, _ = _get(
            f"{base}/api/v1/auth/login", {"email": "admin@clinic.test", "password": "wrong one"}
        )
        assert status == 401
    finally:
        stop(proc)
