"""The server alone, for the browser tests of pages that need no device (the report, the
prescription form): ``ankle server`` in a process of its own with the demo's records, and
the demo therapist's REST client as the independent witness of what a page did."""

from __future__ import annotations

import concurrent.futures
import os
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest

from server.cli import provision_demo, wait_healthy
from server.config import Settings
from tests.browser.rest import signed_in
from tests.system.harness import free_port

API = "/api/v1"


@dataclass
class Clinic:
    """The server alone with the demo's records."""

    url: str
    creds: dict[str, Any]


@pytest.fixture
def therapist(clinic: Clinic) -> Iterator[httpx.Client]:
    """The demo therapist's REST client: the independent witness of what the page did."""
    with httpx.Client(base_url=f"{clinic.url}{API}", timeout=30) as client:
        yield signed_in(client, clinic.creds, "/auth/login")


@pytest.fixture
def clinic(tmp_path: Path) -> Iterator[Clinic]:
    port = free_port()
    settings = Settings(data_dir=tmp_path / "server", port=port)
    with concurrent.futures.ThreadPoolExecutor(1) as pool:  # Playwright holds this loop
        creds = pool.submit(provision_demo, settings).result()
    env = {**os.environ, "ANKLE_DATA_DIR": str(settings.data_dir), "ANKLE_PORT": str(port)}
    with (tmp_path / "server.log").open("wb") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "ankle", "server"], env=env, stdout=log, stderr=log
        )
    url = f"http://127.0.0.1:{port}"
    try:
        wait_healthy(url, proc, timeout=60.0)
        yield Clinic(url, creds)
    finally:
        proc.terminate()
        proc.wait(30)
