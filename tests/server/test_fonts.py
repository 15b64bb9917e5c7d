"""The report's typeface: DejaVu Sans where it can be found, reportlab's Vera otherwise."""

from __future__ import annotations

import shutil
from pathlib import Path

from server import fonts


def test_the_systems_dejavu_sans_comes_first_and_vera_last() -> None:
    found = fonts.candidates()
    assert [what for what, *_ in found[: len(fonts.SYSTEM_DIRS)]] == [
        "DejaVu Sans (the system's)"
    ] * len(fonts.SYSTEM_DIRS)
    what, folder, files = found[-1]
    assert what.startswith("Vera") and files == fonts.VERA
    assert all((folder / name).is_file() for name in files)  # reportlab ships it


def test_a_missing_font_falls_back_to_the_next_and_last_to_vera(tmp_path: Path) -> None:
    system, mpl = tmp_path / "system", tmp_path / "mpl"
    system.mkdir()
    mpl.mkdir()
    *_, vera = fonts.candidates()
    found = [
        ("DejaVu Sans (the system's)", system, fonts.DEJAVU),
        ("DejaVu Sans (matplotlib's)", mpl, fonts.DEJAVU),
        vera,
    ]
    assert fonts.choose(found) == vera  # neither DejaVu is there
    shutil.copy(vera[1] / "Vera.ttf", system / "DejaVuSans.ttf")  # a regular face alone
    assert fonts.choose(found) == vera  # is not enough: the headings are bold
    for name in fonts.DEJAVU:
        shutil.copy(vera[1] / "Vera.ttf", mpl / name)
    assert fonts.choose(found)[0] == "DejaVu Sans (matplotlib's)"
