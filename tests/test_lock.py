"""The pinned requirements of ``make lock`` cover what each role installs from pyproject.toml."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.test_roles import closure

ROOT = Path(__file__).resolve().parents[1]


def pinned(role: str) -> dict[str, str]:
    text = (ROOT / "requirements" / f"{role}.txt").read_text()
    found = re.findall(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==([^\s;]+)", text, re.MULTILINE)
    return {re.sub(r"[-_.]+", "-", name).lower(): version for name, version in found}


@pytest.mark.parametrize("role", ["device", "station", "server", "dev"])
def test_each_role_lock_pins_every_package_the_role_installs(role: str) -> None:
    pins = pinned(role)
    missing = sorted(closure(role) - set(pins) - {"ankle-telerehab"})
    assert not missing, f"requirements/{role}.txt lacks {missing}: run 'make lock'"


def test_the_device_lock_carries_no_server_packages() -> None:
    assert not {"fastapi", "sqlalchemy", "pyarrow", "matplotlib"} & set(pinned("device"))
    assert "numba" in pinned("device")
