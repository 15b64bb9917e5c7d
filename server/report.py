"""The patient's report for the medical record, as a PDF a clinician reads and signs.

Made with reportlab's page layout (platypus) and its charts, from one
:class:`sessions.record.PatientRecord`: the patient, the period, the prescriptions, sessions
done against prescribed, each session's measures (per direction, named for the patient's
side), their trend, the notable events (faults, holds, early ends) and a signature block.
The numbers are those of :mod:`sessions.measures`, as in the FHIR export.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any
from zoneinfo import ZoneInfo

from reportlab.graphics.charts.legends import LineLegend
from reportlab.graphics.charts.lineplots import LinePlot
from reportlab.graphics.shapes import Drawing, String
from reportlab.lib import colors
from reportlab.lib.pagesizes import A4
from reportlab.lib.styles import ParagraphStyle, getSampleStyleSheet
from reportlab.lib.units import mm
from reportlab.pdfbase.pdfmetrics import stringWidth
from reportlab.platypus import (
    Flowable,
    KeepTogether,
    Paragraph,
    SimpleDocTemplate,
    Spacer,
    Table,
    TableStyle,
)
from reportlab.platypus.doctemplate import BaseDocTemplate

from server import fonts
from sessions.anatomy import label
from sessions.measures import Measure
from sessions.prescription import EXERCISE_LIBRARY, ExerciseKind
from sessions.progress import PrescriptionAdherence, Progress
from sessions.record import PatientRecord, Session, data_missing, ended_early

TITLE = "Ankle rehabilitation report"
_SIDE = {"left": "Left", "right": "Right", "both": "Both"}
_UNIT = {"deg": "°", "N.m": " N·m", "J": " J", "s": " s", "{repetitions}": ""}
_SERIES_COLOURS = (
    colors.HexColor("#1f77b4"),
    colors.HexColor("#d62728"),
    colors.HexColor("#2ca02c"),
    colors.HexColor("#9467bd"),
    colors.HexColor("#ff7f0e"),
    colors.HexColor("#8c564b"),
)
# Set in the typeface that draws every patient's name (server.fonts), not Helvetica.
_STYLES = getSampleStyleSheet()
_BODY = ParagraphStyle("body", parent=_STYLES["BodyText"], fontName=fonts.REGULAR)
_SMALL = ParagraphStyle("small", parent=_BODY, fontSize=8, leading=10)
_H1 = ParagraphStyle("title", parent=_STYLES["Title"], fontName=fonts.BOLD)
_H2 = ParagraphStyle("heading", parent=_STYLES["Heading2"], fontName=fonts.BOLD)
# A word breaks only when it is wider than the page could hold (fit_widths): a reference
# or a title of 120 letters with no space, which the API allows.
_CELL = ParagraphStyle("cell", parent=_BODY, fontSize=8, leading=10, splitLongWords=True)
_HEAD = ParagraphStyle("head", parent=_CELL, fontName=fonts.BOLD)
_CELL_PAD = 6.0
"""Left and right padding of a table cell, points (reportlab's default, set below)."""
_MARGIN = 18 * mm
"""Left and right page margin."""
FRAME_WIDTH = A4[0] - 2 * _MARGIN
"""The width text and tables may take on a page, points; nothing is drawn beyond it."""
_GRID = TableStyle(
    [
        ("GRID", (0, 0), (-1, -1), 0.4, colors.grey),
        ("BACKGROUND", (0, 0), (-1, 0), colors.HexColor("#e8eef4")),
        ("FONTNAME", (0, 0), (-1, -1), fonts.REGULAR),  # else the grid declares Helvetica
        ("LEFTPADDING", (0, 0), (-1, -1), _CELL_PAD),
        ("RIGHTPADDING", (0, 0), (-1, -1), _CELL_PAD),
        ("VALIGN", (0, 0), (-1, -1), "TOP"),
    ]
)


@dataclass(frozen=True)
class Trend:
    """One measure over the period: its first and last value and the change."""

    code: str
    label: str
    unit: str
    first: float
    last: float
    points: list[tuple[float, float]]
    """(days since the period began, value), oldest first."""

    @property
    def sessions(self) -> int:
        return len(self.points)

    @property
    def change(self) -> float:
        return self.last - self.first


def exercise_name(kind: str | None) -> str:
    """The exercise's name in the library (a recording from elsewhere may name another)."""
    try:
        return EXERCISE_LIBRARY[ExerciseKind(kind or "")].name
    except ValueError:
        return kind or "unknown"


def value_text(value: float, unit: str) -> str:
    return f"{value:.1f}{_UNIT.get(unit, ' ' + unit)}"


def _date(t: datetime, zone: ZoneInfo) -> str:
    """The day ``t`` fell on in ``zone``."""
    return f"{t.astimezone(zone):%Y-%m-%d}"


def utc_offset(t: datetime) -> str:
    """``t``'s offset from UTC as ``UTC+01:00`` (to the minute)."""
    minutes = (t.utcoffset() or timedelta()) // timedelta(minutes=1)
    sign = "-" if minutes < 0 else "+"
    return f"UTC{sign}{abs(minutes) // 60:02d}:{abs(minutes) % 60:02d}"


def _start_offset(record: PatientRecord) -> str:
    return utc_offset(record.since.astimezone(record.zone))


def zone_line(record: PatientRecord) -> str:
    """The zone the report's times are in, named once: with its offset at the period's start
    (a time at another offset, across a change to or from summer time, names its own)."""
    return f"times are in {record.zone.key} ({_start_offset(record)})"


def clock(record: PatientRecord, t: datetime) -> str:
    """``t`` on the report's clock (:attr:`PatientRecord.zone`), to the minute; its offset
    added where it is not the one :func:`zone_line` names, so that no time is ambiguous (the
    hour a clock goes back runs twice)."""
    local = t.astimezone(record.zone)
    text = f"{local:%Y-%m-%d %H:%M}"
    offset = utc_offset(local)
    return text if offset == _start_offset(record) else f"{text} {offset}"


def _p(text: str, style: ParagraphStyle = _SMALL) -> Paragraph:
    return Paragraph(text.replace("&", "&amp;").replace("<", "&lt;"), style)


def _table(header: Sequence[str], rows: Sequence[Sequence[str]], widths: Sequence[float]) -> Table:
    """A grid whose every cell wraps between words and never inside one: ``widths`` are the
    columns' designed widths; a column whose longest word (a date, "interrupted", a header
    word) would not fit takes the room from columns that have some to spare, so a word
    never runs into its neighbour or breaks in two, whatever the typeface's widths."""
    cells = [[_p(h, _HEAD) for h in header]]
    cells += [[_p(c, _CELL) for c in row] for row in rows]
    least = [
        max(_longest_word(h, fonts.BOLD), *(_longest_word(r[i], fonts.REGULAR) for r in rows))
        + 2 * _CELL_PAD
        for i, h in enumerate(header)
    ]
    table = Table(cells, colWidths=fit_widths(widths, least, FRAME_WIDTH), repeatRows=1)
    table.setStyle(_GRID)
    return table


def fit_widths(
    wanted: Sequence[float], least: Sequence[float], most: float = math.inf
) -> list[float]:
    """Column widths as ``wanted``, none below its ``least``: a column that needs more takes
    it from the others' slack, in proportion, so the table keeps its width; only when all
    the slack is too little does the table grow (a word is not cut), up to ``most`` (the
    page's width). Past that the widest needs are cut down to one level, so the table fits
    the page and only a word wider than its column there breaks (a name of 120 letters
    with no space, which the API allows, pushed the table 428 pt off the page's left)."""
    widths = [max(w, m) for w, m in zip(wanted, least, strict=True)]
    over = sum(widths) - sum(wanted)
    slack = [w - m for w, m in zip(widths, least, strict=True)]
    if over > 0 and sum(slack) > 0:
        share = min(1.0, over / sum(slack))
        widths = [w - x * share for w, x in zip(widths, slack, strict=True)]
    if sum(widths) <= most:
        return widths
    # The level L at which sum(min(w, L)) is ``most``: the narrow columns keep their width.
    room, level = most, 0.0
    for i, w in enumerate(ordered := sorted(widths)):
        left = len(ordered) - i
        if w * left >= room:
            level = room / left
            break
        room -= w
    return [min(w, level) for w in widths]


def _longest_word(text: str, font: str) -> float:
    return max((stringWidth(w, font, _CELL.fontSize) for w in text.split()), default=0.0)


def trends(record: PatientRecord) -> list[Trend]:
    """Per measure code and direction (angles, torques and work), its values over the
    sessions of the period, in order."""
    series: dict[str, tuple[Measure, list[tuple[float, float]]]] = {}
    for s in record.sessions:
        day = (s.started_at - record.since).total_seconds() / 86400
        for m in record.measures(s):
            if m.code.unit not in ("deg", "N.m", "J"):
                continue
            series.setdefault(m.code.code, (m, []))[1].append((day, m.value))
    return [
        Trend(m.code.code, m.label, m.code.unit, pts[0][1], pts[-1][1], pts)
        for m, pts in series.values()
    ]


def progress_section(rows: Sequence[Trend]) -> list[Flowable]:
    """The progress table and the peak-angle chart, from the rows given."""
    out: list[Flowable] = [Paragraph("Progress over the period", _H2)]
    if not rows:
        return [*out, _p("No measures in this period.", _BODY)]
    out.append(
        _table(
            ["Measure", "Sessions", "First", "Last", "Change"],
            [
                [
                    t.label,
                    str(t.sessions),
                    value_text(t.first, t.unit),
                    value_text(t.last, t.unit),
                    f"{t.change:+.1f}{_UNIT.get(t.unit, ' ' + t.unit)}",
                ]
                for t in rows
            ],
            [70 * mm, 20 * mm, 25 * mm, 25 * mm, 25 * mm],
        )
    )
    angles = [t for t in rows if t.code.startswith("peak-angle-")]
    if angles:
        out += [Spacer(1, 4 * mm), _chart(angles, "Peak angle per session (degrees)")]
    return out


def _chart(rows: Sequence[Trend], title: str) -> Drawing:
    drawing = Drawing(170 * mm, 70 * mm)
    plot = LinePlot()
    plot.x, plot.y = 15 * mm, 12 * mm
    plot.width, plot.height = 105 * mm, 48 * mm
    plot.data = [t.points for t in rows]
    for i, _ in enumerate(rows):
        plot.lines[i].strokeColor = _SERIES_COLOURS[i % len(_SERIES_COLOURS)]
        plot.lines[i].strokeWidth = 1.2
    plot.xValueAxis.labelTextFormat = "%d"
    plot.xValueAxis.labels.fontSize = plot.yValueAxis.labels.fontSize = 7
    plot.xValueAxis.labels.fontName = plot.yValueAxis.labels.fontName = fonts.REGULAR
    plot.yValueAxis.labelTextFormat = "%.0f"
    drawing.add(plot)
    legend = LineLegend()
    legend.x, legend.y = 125 * mm, 58 * mm
    legend.fontSize, legend.fontName = 7, fonts.REGULAR
    legend.colorNamePairs = [
        (_SERIES_COLOURS[i % len(_SERIES_COLOURS)], t.label[:40]) for i, t in enumerate(rows)
    ]
    drawing.add(legend)
    drawing.add(String(15 * mm, 64 * mm, title, fontSize=9, fontName=fonts.REGULAR))
    drawing.add(
        String(55 * mm, 2 * mm, "days since the period began", fontSize=7, fontName=fonts.REGULAR)
    )
    return drawing


def _adherence_rows(rows: Sequence[PrescriptionAdherence]) -> list[list[Any]]:
    """Per prescription, over its prescribed weeks that are over in the period (the week in
    progress misses nothing yet): never more completed than prescribed."""
    return [
        [
            a.title or exercise_name(a.exercise),
            f"{a.sessions_per_week}",
            str(a.prescribed),
            str(a.completed),
            str(a.extra),
            str(a.ended_early),
            str(a.missed),
            "" if a.percent is None else f"{a.percent:.0f} %",
        ]
        for a in rows
    ]


def baseline_section(progress: Progress, side: str | None, zone: ZoneInfo) -> list[Flowable]:
    """Active range per direction in the ROM assessments against the first one, each change
    judged against the MDC95 of the device's own repeated trials; days are ``zone``'s."""
    out: list[Flowable] = [Paragraph("Range of motion against the baseline", _H2)]
    if progress.baseline is None:
        return [*out, _p("No ROM assessment yet: there is no baseline.", _BODY)]
    first = _date(progress.baseline.at, zone)
    out.append(_p(f"Baseline: the first ROM assessment, {first}.", _BODY))
    mdc = {(m.axis, m.sign): m for m in progress.mdc}
    rows: list[list[Any]] = []
    for ex in progress.exercises:
        if ex.exercise != ExerciseKind.ROM_ASSESSMENT:
            continue
        for m in ex.measures:
            if m.baseline is None or not m.points or m.sign == 0:
                continue
            last = m.points[-1]
            limit = mdc.get((m.axis, m.sign))
            judged = (
                "not judged: no MDC95"
                if last.real_change is None
                else ("beyond MDC95: a real change" if last.real_change else "within MDC95")
            )
            rows.append(
                [
                    label(m.axis, m.sign, side),  # type: ignore[arg-type]
                    value_text(m.baseline, "deg"),
                    f"{value_text(last.value, 'deg')} ({_date(last.at, zone)})",
                    "" if last.change is None else f"{last.change:+.1f}°",
                    limit.text if limit is not None else "",
                    judged,
                ]
            )
    if rows:
        out.append(
            _table(
                ["Direction", "Baseline", "Latest", "Change", "MDC95", "Judged"],
                rows,
                [38 * mm, 18 * mm, 32 * mm, 16 * mm, 40 * mm, 28 * mm],
            )
        )
    return out


def _measures_text(measures: list[Measure]) -> str:
    return "; ".join(
        f"{m.label}: {value_text(m.value, m.code.unit)}"
        for m in measures
        if m.code.unit != "{repetitions}"
    )


def session_name(record: PatientRecord, s: Session) -> str:
    """What a session ran, as the therapist named it: its prescription's title (every session
    was "Strength (resistive)", the library's name for its kind, whatever its title said),
    else the exercise's name."""
    titles = {rx.id: rx.title for rx in record.prescriptions}
    return titles.get(s.prescription_id or 0) or exercise_name(s.exercise)


def _session_rows(record: PatientRecord) -> list[list[Any]]:
    rows = []
    for s in record.sessions:
        summary = s.summary or {}
        done, asked = summary.get("repetitions_completed"), summary.get("repetitions_prescribed")
        reps = "" if done is None else f"{done} of {asked}" if asked is not None else str(done)
        rows.append(
            [
                clock(record, s.started_at),
                session_name(record, s),
                s.end_reason or "no end record",
                reps,
                _measures_text(record.measures(s)) or "no summary",
            ]
        )
    return rows


def notable_events(s: Session) -> list[str]:
    """What a clinician should know of a session: faults and safety stops, holds, an end
    before the prescription's."""
    summary = s.summary or {}
    found = [
        f"{f.get('kind', 'event')} at {float(f.get('at_s', 0.0)):.0f} s "
        f"({f.get('by', '?')}): {f.get('text', '')}"
        for f in summary.get("faults", [])
    ]
    holds = int(summary.get("events", {}).get("hold", 0))
    if holds:
        found.append(f"held {holds} time{'s' if holds != 1 else ''}")
    if ended_early(s):
        why = summary.get("end_text") or ""
        found.append(f"ended early ({s.end_reason}){': ' + why if why else ''}")
    missing = data_missing(summary)
    if missing:
        found.append(missing[0].lower() + missing[1:])
    return found


def _event_rows(record: PatientRecord) -> list[list[Any]]:
    return [
        [clock(record, s.started_at), session_name(record, s), text]
        for s in record.sessions
        for text in notable_events(s)
    ]


def _signature() -> Flowable:
    line = "_" * 38
    return KeepTogether(
        [
            Spacer(1, 10 * mm),
            Paragraph("Clinician's review", _H2),
            _p(f"Name: {line}", _BODY),
            Spacer(1, 6 * mm),
            _p(f"Signature: {line}      Date: {'_' * 16}", _BODY),
        ]
    )


_FOOTER_SIZE = 7


def fitted(text: str, font: str, size: float, width: float) -> str:
    """``text`` cut with "…" to be at most ``width`` points wide in ``font`` at ``size``."""
    if stringWidth(text, font, size) <= width:
        return text
    low, high = 0, len(text)  # the longest prefix that fits with the ellipsis
    while low < high:
        mid = (low + high + 1) // 2
        if stringWidth(text[:mid] + "…", font, size) <= width:
            low = mid
        else:
            high = mid - 1
    return text[:low] + "…"


def _footer(canvas: Any, doc: BaseDocTemplate) -> None:
    canvas.saveState()
    canvas.setFont(fonts.REGULAR, _FOOTER_SIZE)
    page = f"page {doc.page}"
    # The title holds the patient's name, up to 120 characters: cut short of the page number.
    room = FRAME_WIDTH - stringWidth(page, fonts.REGULAR, _FOOTER_SIZE) - 6 * mm
    canvas.drawString(doc.leftMargin, 10 * mm, fitted(doc.title, fonts.REGULAR, _FOOTER_SIZE, room))
    canvas.drawRightString(A4[0] - doc.rightMargin, 10 * mm, page)
    canvas.restoreState()


def pdf(record: PatientRecord) -> bytes:
    """The report as PDF bytes."""
    fonts.register()
    p = record.patient
    first, last = record.days
    period = f"{first} to {last}"
    story: list[Flowable] = [
        Paragraph(TITLE, _H1),
        _table(
            ["Patient", "Reference", "Birth year", "Affected side", "Period"],
            [
                [
                    p.display_name,
                    p.reference or "none",
                    "unknown" if p.birth_year is None else str(p.birth_year),
                    _SIDE.get(p.affected_side or "", "not recorded"),
                    period,
                ]
            ],
            [45 * mm, 30 * mm, 20 * mm, 25 * mm, 50 * mm],
        ),
        _p(f"Generated {clock(record, record.generated_at)}; {zone_line(record)}.", _SMALL),
        Paragraph("Prescriptions", _H2),
    ]
    if record.prescriptions:
        story.append(
            _table(
                ["Prescription", "Exercise", "Status", "Per week", "Prescribed on"],
                [
                    [
                        rx.title or rx.exercise,
                        exercise_name(rx.exercise),
                        rx.status,
                        "" if rx.sessions_per_week is None else str(rx.sessions_per_week),
                        _date(rx.created_at, record.zone),
                    ]
                    for rx in record.prescriptions
                ],
                [55 * mm, 35 * mm, 22 * mm, 20 * mm, 30 * mm],
            )
        )
    else:
        story.append(_p("No prescriptions in force during this period.", _BODY))
    story.append(Paragraph("Sessions done against prescribed", _H2))
    if record.progress.adherence:
        story.append(
            _table(
                [
                    "Prescription",
                    "Per week",
                    "Prescribed",
                    "Completed",
                    "Extra",
                    "Ended early",
                    "Missed",
                    "Done",
                ],
                _adherence_rows(record.progress.adherence),
                [50 * mm, 16 * mm, 19 * mm, 19 * mm, 13 * mm, 19 * mm, 15 * mm, 15 * mm],
            )
        )
        story.append(
            _p(
                "Counted per prescribed week (from the day it was prescribed), over the weeks "
                "that are over; sessions beyond those prescribed are extra.",
                _BODY,
            )
        )
    n = len(record.sessions)
    story.append(_p(f"{n} session{'' if n == 1 else 's'} in the period.", _BODY))
    story.append(Paragraph("Sessions", _H2))
    if record.sessions:
        story.append(
            _table(
                ["Date", "Exercise", "Ended", "Repetitions", "Measures"],
                _session_rows(record),
                [26 * mm, 24 * mm, 20 * mm, 20 * mm, 80 * mm],
            )
        )
    else:
        story.append(_p("No sessions in this period.", _BODY))
    story += progress_section(trends(record))
    story += baseline_section(record.progress, record.patient.affected_side, record.zone)
    story.append(Paragraph("Notable events", _H2))
    events = _event_rows(record)
    if events:
        widths = [30 * mm, 30 * mm, 110 * mm]
        story.append(_table(["Date", "Exercise", "What happened"], events, widths))
    else:
        story.append(_p("No faults, holds or early ends in this period.", _BODY))
    story.append(_signature())

    out = io.BytesIO()
    doc = SimpleDocTemplate(
        out,
        pagesize=A4,
        title=f"{TITLE}: {p.display_name}, {period}",
        author="Ankle telerehabilitation server",
        leftMargin=_MARGIN,
        rightMargin=_MARGIN,
        topMargin=16 * mm,
        bottomMargin=18 * mm,
        initialFontName=fonts.REGULAR,  # else every page also declares Helvetica
    )
    doc.build(story, onFirstPage=_footer, onLaterPages=_footer)
    return out.getvalue()
