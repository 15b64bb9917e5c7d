"""The deployment files agree with the code they deploy, and nginx accepts its sample."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from device.service import REALTIME_PRIORITY
from server.config import Settings
from server.routes.uploads import CHUNK_MAX
from sessions import wire

DEPLOY = Path(__file__).resolve().parents[1] / "deploy"
NGINX = DEPLOY / "nginx" / "ankle.conf"


def unit(name: str) -> dict[str, list[str]]:
    """A systemd unit's keys (every value of a repeated key), continuation lines joined."""
    text = (DEPLOY / "systemd" / name).read_text().replace("\\\n", " ")
    keys: dict[str, list[str]] = {}
    for line in text.splitlines():
        if "=" in line and not line.lstrip().startswith(("#", "[")):
            key, value = line.split("=", 1)
            keys.setdefault(key.strip(), []).append(value.strip())
    return keys


def _size(text: str) -> int:
    number, suffix = re.fullmatch(r"(\d+)([kKmM]?)", text).groups()  # type: ignore[union-attr]
    return int(number) * {"": 1, "k": 1024, "m": 1024 * 1024}[suffix.lower()]


def _seconds(text: str) -> float:
    number, suffix = re.fullmatch(r"(\d+)(ms|s|m)?", text).groups()  # type: ignore[union-attr]
    return int(number) * {"ms": 0.001, "s": 1.0, None: 1.0, "m": 60.0}[suffix]


def directive(name: str) -> list[str]:
    return re.findall(rf"^\s*{name}\s+([^;]+);", NGINX.read_text(), re.MULTILINE)


def test_the_device_unit_grants_what_the_service_asks_for() -> None:
    keys = unit("ankle-device.service")
    assert "CAP_SYS_NICE" in keys["AmbientCapabilities"][0].split()
    assert int(keys["LimitRTPRIO"][0]) >= REALTIME_PRIORITY
    assert keys["User"][0] != "root"
    assert "ankle device" in keys["ExecStart"][0] and "--sim" not in keys["ExecStart"][0]


def test_every_role_has_a_unit_that_runs_the_installed_command() -> None:
    for name, command in [
        ("ankle-server@.service", "ankle server"),
        ("ankle-station.service", "ankle station"),
        ("ankle-device.service", "ankle device"),
    ]:
        keys = unit(name)
        assert command in keys["ExecStart"][0], name
        assert keys["Restart"][0] in {"always", "on-failure"}, name
    server = unit("ankle-server@.service")
    assert "--port %i" in server["ExecStart"][0] and "--host 127.0.0.1" in server["ExecStart"][0]


def test_the_proxy_sample_fits_the_servers_limits_and_heartbeats() -> None:
    (body,) = directive("client_max_body_size")
    assert _size(body) >= max(Settings().body_max_bytes, CHUNK_MAX)
    for timeout in ("proxy_read_timeout", "proxy_send_timeout"):
        (value,) = directive(timeout)
        assert _seconds(value) > wire.HEARTBEAT_TIMEOUT_S, timeout
    text = NGINX.read_text()
    assert len(re.findall(r"^\s*server 127\.0\.0\.1:\d+", text, re.MULTILINE)) >= 2
    for websocket in ("/ws/", "/scene/"):
        assert f"location {websocket}" in text
    assert "proxy_set_header Upgrade $http_upgrade" in text
    assert re.search(r"listen 443 ssl http2", text)


@pytest.mark.skipif(shutil.which("nginx") is None, reason="nginx is not installed here")
def test_nginx_accepts_the_sample(tmp_path: Path) -> None:
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1",
         "-subj", "/CN=rehab.clinic.example",
         "-keyout", tmp_path / "privkey.pem", "-out", tmp_path / "fullchain.pem"],
        check=True, capture_output=True,
    )  # fmt: skip
    site = NGINX.read_text().replace("/etc/ssl/rehab.clinic.example", str(tmp_path))
    (tmp_path / "site.conf").write_text(site)
    (tmp_path / "nginx.conf").write_text(
        f"pid {tmp_path}/nginx.pid; error_log {tmp_path}/error.log;\n"
        f"events {{}}\nhttp {{ access_log off; include {tmp_path}/site.conf; }}\n"
    )
    done = subprocess.run(
        ["nginx", "-t", "-p", str(tmp_path), "-c", str(tmp_path / "nginx.conf")],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr


CADDY = DEPLOY / "caddy" / "Caddyfile"


def test_the_caddy_sample_fits_the_servers_limits_and_heartbeats() -> None:
    text = CADDY.read_text()
    (size,) = re.findall(r"max_size (\d+)MB", text)
    assert int(size) * 1000 * 1000 >= max(Settings().body_max_bytes, CHUNK_MAX)
    for timeout in re.findall(r"(?:read|write)_timeout (\S+)", text):
        assert _seconds(timeout) > wire.HEARTBEAT_TIMEOUT_S
    assert len(re.findall(r"127\.0\.0\.1:\d+", text)) >= 2


@pytest.mark.skipif(shutil.which("caddy") is None, reason="caddy is not installed here")
def test_caddy_accepts_the_sample(tmp_path: Path) -> None:
    done = subprocess.run(
        ["caddy", "validate", "--config", str(CADDY), "--adapter", "caddyfile"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={"HOME": str(tmp_path), "PATH": "/usr/bin:/bin:/usr/local/bin"},
    )
    assert done.returncode == 0, done.stderr
    assert "Valid configuration" in done.stdout + done.stderr
