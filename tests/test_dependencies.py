"""The package dependency direction of DESIGN.md section 5, enforced on the source."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("device", "sessions", "station", "server", "webui", "lab", "ankle")
ALLOWED: dict[str, set[str]] = {
    "device": set(),
    "sessions": {"device"},
    "station": {"device", "sessions"},
    "server": {"device", "sessions"},
    "webui": {"device", "sessions", "server"},
    # The lab measures everything; only the composition root may use it.
    "lab": {"device", "sessions", "station", "server", "webui"},
    "ankle": {"device", "sessions", "station", "server", "webui", "lab"},
}
# Third-party libraries that may be imported only in the named places.
CONFINED: dict[str, tuple[str, ...]] = {
    "serial": ("device/transport",),
    "serial_asyncio_fast": ("device/transport",),
    "fastapi": ("server/", "webui/"),
    "viser": ("webui/",),
}


def imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module.split(".")[0])
    return found


def sources() -> list[Path]:
    return [p for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))]


def test_every_package_exists() -> None:
    for pkg in PACKAGES:
        assert (ROOT / pkg / "__init__.py").is_file(), pkg


@pytest.mark.parametrize("path", sources(), ids=lambda p: str(p.relative_to(ROOT)))
def test_nothing_imports_upward(path: Path) -> None:
    pkg = path.relative_to(ROOT).parts[0]
    wrong = (imports(path) & set(PACKAGES)) - ALLOWED[pkg] - {pkg}
    assert not wrong, f"{path.relative_to(ROOT)} imports {sorted(wrong)}"


@pytest.mark.parametrize("path", sources(), ids=lambda p: str(p.relative_to(ROOT)))
def test_confined_libraries_stay_in_their_place(path: Path) -> None:
    rel = path.relative_to(ROOT).as_posix()
    for lib, places in CONFINED.items():
        if lib in imports(path):
            assert rel.startswith(places), f"{rel} imports {lib}; only {places} may"


def test_only_the_composition_root_imports_the_lab() -> None:
    users = {p.relative_to(ROOT).parts[0] for p in sources() if "lab" in imports(p)}
    assert users <= {"lab", "ankle"}, sorted(users)


def test_the_checker_sees_an_upward_import(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("from server import app\nimport viser\n")
    assert {"server", "viser"} <= imports(bad)
