"""The typeface of the PDF report: one that draws every patient's name.

The standard PDF fonts (Helvetica) and reportlab's own Vera draw Western European letters
only: "Łukasz Żółć", "Ελένη" or "Ольга" come out as boxes or are dropped. The report is set
in DejaVu Sans (Latin, Greek and Cyrillic, and the symbols it uses: ° · ±), embedded as
TrueType. No pip package the server carries ships it and nothing of it is kept in this
repository, so it is found at run time: the system's (Debian's ``fonts-dejavu-core``, which
a server should have installed), else the copy matplotlib ships where matplotlib is
installed (the lab and development installs), else reportlab's Vera, which draws Western
European letters only. The server logs which it uses, once, and warns for Vera.

:func:`register` makes :data:`REGULAR` and :data:`BOLD` known to reportlab; the report's
styles name them.
"""

from __future__ import annotations

import functools
import importlib.util
import logging
from pathlib import Path

import reportlab
from reportlab.lib.fonts import addMapping
from reportlab.pdfbase import pdfmetrics
from reportlab.pdfbase.ttfonts import TTFont

log = logging.getLogger("ankle.server.report")

REGULAR = "ReportSans"
BOLD = "ReportSans-Bold"

SYSTEM_DIRS = (
    Path("/usr/share/fonts/truetype/dejavu"),  # Debian, Ubuntu: fonts-dejavu-core
    Path("/usr/share/fonts/dejavu-sans-fonts"),  # Fedora, RHEL: dejavu-sans-fonts
    Path("/usr/share/fonts/TTF"),  # Arch: ttf-dejavu
)
"""Where Linux distributions keep DejaVu Sans."""
DEJAVU = ("DejaVuSans.ttf", "DejaVuSans-Bold.ttf")
VERA = ("Vera.ttf", "VeraBd.ttf")
Candidate = tuple[str, Path, tuple[str, str]]
"""What it is, the folder, and the regular and bold files' names."""


def _matplotlib_dir() -> Path | None:
    # Found without importing matplotlib: only its files are wanted, and the server's role
    # does not install it (an import there is refused).
    try:
        spec = importlib.util.find_spec("matplotlib")
    except ImportError:
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations))) / "mpl-data" / "fonts" / "ttf"


def candidates() -> list[Candidate]:
    """The typefaces in the order they are tried."""
    out: list[Candidate] = [("DejaVu Sans (the system's)", d, DEJAVU) for d in SYSTEM_DIRS]
    mpl = _matplotlib_dir()
    if mpl is not None:
        out.append(("DejaVu Sans (matplotlib's)", mpl, DEJAVU))
    vera = Path(reportlab.__file__).parent / "fonts"
    out.append(("Vera (Western European letters only)", vera, VERA))
    return out


def choose(found: list[Candidate]) -> Candidate:
    """The first candidate whose regular and bold files are both there."""
    for what, folder, (regular, bold) in found:
        if (folder / regular).is_file() and (folder / bold).is_file():
            return what, folder, (regular, bold)
    raise RuntimeError("no TrueType font for the PDF report: reportlab's own Vera is missing")


@functools.cache
def register() -> str:
    """Register the report's typeface with reportlab, once; answers which one it is."""
    what, folder, (regular, bold) = choose(candidates())
    pdfmetrics.registerFont(TTFont(REGULAR, str(folder / regular)))
    pdfmetrics.registerFont(TTFont(BOLD, str(folder / bold)))
    # <b> in a paragraph, and a bold style, use the bold face.
    addMapping(REGULAR, 0, 0, REGULAR)
    addMapping(REGULAR, 0, 1, REGULAR)
    addMapping(REGULAR, 1, 0, BOLD)
    addMapping(REGULAR, 1, 1, BOLD)
    if what.startswith("DejaVu"):
        log.info("the PDF report is set in %s from %s", what, folder)
    else:
        log.warning(
            "the PDF report is set in %s from %s: DejaVu Sans was not found (install "
            "fonts-dejavu-core), so names beyond Western European letters print as boxes",
            what,
            folder,
        )
    return what
