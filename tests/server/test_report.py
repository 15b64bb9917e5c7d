"""The patient's report for the medical record: the PDF read back with pypdf, the FHIR
bundle validated with fhir.resources' R4B models, both audited, guarded and dated."""

from __future__ import annotations

import io
import math
import re
from datetime import UTC, date, datetime, timedelta
from pathlib import Path
from typing import Any
from urllib.parse import unquote
from zoneinfo import ZoneInfo

import numpy as np
import pytest
from fhir.resources.R4B.bundle import Bundle
from fhir.resources.R4B.codesystem import CodeSystem
from numpy.typing import NDArray
from pypdf import PdfReader
from reportlab.lib.units import mm
from reportlab.pdfbase import pdfmetrics
from sqlalchemy import update

from server import fonts, report
from server.models import Prescription
from server.routes.sessions import RANGES_MAX
from sessions.anatomy import LABELS
from sessions.export import FORMATS
from sessions.fhir import LATERALITY_EXTENSION
from sessions.measures import CODES, code_table_markdown, measures, system_url
from sessions.prescription import EXERCISE_LIBRARY, ExerciseKind
from sessions.recording import SessionEvent
from sessions.summary import AxisSummary, Summary
from tests.server.live_server import STRENGTH, Live, World, bearer
from tests.server.test_progress_route import DAY, assessment_rows, prescribe
from tests.server.test_progress_route import upload as upload_assessment
from tests.server.test_series import (
    HZ,
    PEAK_DEG,
    PITCH,
    TORQUE_PEAK_NM,
    TROUGH_DEG,
    samples,
    upload,
)

pytestmark = pytest.mark.both_stores

ROOT = Path(__file__).resolve().parents[2]
TODAY = datetime.now(UTC).date()


def rows_at(day: date, scale: float = 1.0) -> NDArray[np.void]:
    """The series test's session, started at noon on ``day``, its angles times ``scale``."""
    rows = samples()
    start = datetime(day.year, day.month, day.day, 12, tzinfo=UTC).timestamp()
    rows["wall"] = start + np.arange(len(rows)) / HZ
    rows["pose"][:, PITCH] *= scale
    return rows


async def two_sessions(live: Live, world: World) -> tuple[date, date]:
    """A completed session ten days ago and, three days ago, one the station ended after a
    fault and a hold, with angles 1.2 times larger. Returns their days."""
    first, second = TODAY - timedelta(days=10), TODAY - timedelta(days=3)
    await upload(live, world, rows_at(first))
    wall = datetime(second.year, second.month, second.day, 12, tzinfo=UTC).timestamp()
    events = [
        SessionEvent(wall=wall + 20, kind="hold", by=f"therapist:{world.t1_id}"),
        SessionEvent(wall=wall + 30, kind="fault", by="device", detail={"text": "supply lost"}),
    ]
    await upload(
        live,
        world,
        rows_at(second, 1.2),
        events=events,
        reason="interrupted",
        end_text="held longer than 180 s",
    )
    return first, second


async def exports(live: Live, world: World) -> list[dict[str, Any]]:
    r = await live.client.get(
        "/audit", params={"action": "patient.export"}, headers=bearer(world.admin)
    )
    assert r.status_code == 200, r.text
    rows: list[dict[str, Any]] = r.json()
    return rows


def pdf_text(body: bytes) -> str:
    text = "\n".join(page.extract_text() for page in PdfReader(io.BytesIO(body)).pages)
    return re.sub(r"\s+", " ", text)


def disposition_name(r: Any) -> str:
    """The name a browser saves the file under: ``filename*`` if given, else ``filename``;
    ``filename`` is always given, in ASCII, for clients that read nothing else."""
    header = r.headers["content-disposition"]
    match = re.fullmatch(
        r"attachment; filename=\"([A-Za-z0-9._-]+)\"(?:; filename\*=UTF-8''([^;\s]+))?", header
    )
    assert match, header
    return unquote(match.group(2)) if match.group(2) else match.group(1)


def ascii_fallback(r: Any) -> str:
    match = re.match(r'attachment; filename="([^"]+)"', r.headers["content-disposition"])
    assert match, r.headers["content-disposition"]
    return match.group(1)


@pytest.mark.asyncio
async def test_the_pdf_report_says_what_happened_over_the_period(live: Live, world: World) -> None:
    t1 = bearer(world.t1)
    r = await live.client.patch(
        f"/patients/{world.p1}", json={"reference": "CL 7/ä", "birth_year": 1950}, headers=t1
    )
    assert r.status_code == 200, r.text
    # Titled by the therapist: sessions are named by it, not by the library's "Strength
    # (resistive)" (every session was, whatever its prescription's title).
    r = await live.client.patch(
        f"/prescriptions/{world.rx1}", json={**STRENGTH, "title": "Toe pushes"}, headers=t1
    )
    assert r.status_code == 200, r.text
    # Prescribed two weeks ago: week 1 holds the completed session, week 2 the one ended early.
    async with live.app.state.sessionmaker() as db:
        await db.execute(
            update(Prescription)
            .where(Prescription.patient_id == world.p1)
            .values(created_at=datetime.now(UTC) - timedelta(days=14))
        )
        await db.commit()
    first, _ = await two_sessions(live, world)
    since, until = first - timedelta(days=1), TODAY
    r = await live.client.get(
        f"/patients/{world.p1}/report.pdf",
        params={"since": str(since), "until": str(until)},
        headers=t1,
    )
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/pdf"
    assert r.headers["cache-control"] == "no-store"
    assert disposition_name(r) == f"report-CL-7-ä-{since:%Y%m%d}-{until:%Y%m%d}.pdf"
    assert ascii_fallback(r) == f"report-CL-7-a-{since:%Y%m%d}-{until:%Y%m%d}.pdf"
    text = pdf_text(r.content)

    for fact in ("Pat One", "CL 7/ä", "1950", "Left", f"{since} to {until}"):
        assert fact in text, fact
    assert "Toe pushes Strength (resistive) active" in text, text  # title, then its kind
    assert "2 sessions in the period" in text
    sessions = text[text.index("Date Exercise Ended") :]
    assert "Strength (resistive)" not in sessions, sessions
    assert sessions.count("Toe pushes") == 2 + 3, sessions  # 2 sessions, 3 notable events
    # Per direction, named for a left foot's pitch (the same words on either foot).
    assert f"{LABELS['plantarflexion']}: {PEAK_DEG:.1f}°" in text
    assert f"{LABELS['dorsiflexion']}: {-TROUGH_DEG:.1f}°" in text
    assert f"Peak torque about the pitch axis: {abs(TORQUE_PEAK_NM):.1f} N·m" in text
    # Per prescribed week that is over (5 a week, two weeks): 1 completed, none extra, 1 ended
    # early, 8 missed, 10 % done: the same computation as the patient's page.
    assert "Toe pushes 5 10 1 0 1 8 10 %" in text, text
    # The trend: the peak plantarflexion grew with the second session's larger angles.
    assert "Progress over the period" in text
    grown = PEAK_DEG * 1.2
    trend = f"{LABELS['plantarflexion']} 2 {PEAK_DEG:.1f}° {grown:.1f}° {grown - PEAK_DEG:+.1f}°"
    assert trend in text, text
    # Notable events: the second session's hold, fault and early end.
    assert "fault at 30 s (device): supply lost" in text
    assert "held 1 time" in text
    assert "ended early (interrupted): held longer than 180 s" in text
    assert "Signature" in text

    (row,) = await exports(live, world)
    assert row["actor"] == f"user:{world.t1_id}" and row["patient_id"] == world.p1
    assert row["new"] == {
        "format": "pdf",
        "since": str(since),
        "until": str(until),
        "tz": "UTC",
        "sessions": 2,
    }


@pytest.mark.asyncio
async def test_the_fhir_bundle_is_valid_r4_with_ucum_units_and_laterality(
    live: Live, world: World
) -> None:
    await two_sessions(live, world)
    t1 = bearer(world.t1)
    r = await live.client.get(f"/patients/{world.p1}/fhir", headers=t1)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/fhir+json"
    first_day = TODAY - timedelta(days=89)
    assert disposition_name(r) == (
        f"report-patient-{world.p1}-{first_day:%Y%m%d}-{TODAY:%Y%m%d}.fhir.json"
    )
    body = r.json()
    bundle = Bundle.model_validate(body)  # raises on anything R4B does not allow
    assert bundle.type == "collection"
    # The project's own names are the site's: its code system is served where it says.
    site = live.settings.fhir_base
    system = system_url(site)
    assert system == f"{live.settings.public_url}/api/v1/fhir/CodeSystem/session-measures"

    patient, *observations = [e["resource"] for e in body["entry"]]
    assert patient["resourceType"] == "Patient" and patient["name"] == [{"text": "Pat One"}]
    subject = body["entry"][0]["fullUrl"]
    assert len(observations) == 2 * 8  # per session: 2 peak angles, ROM, 2 torques, work,
    # exercise time and repetitions (the strength exercise moves pitch only)
    units = {o["valueQuantity"]["code"] for o in observations}
    assert {"deg", "N.m", "J", "s"} <= units
    for o in observations:
        assert o["subject"] == {"reference": subject}
        assert o["valueQuantity"]["system"] == "http://unitsofmeasure.org"
        assert math.isfinite(o["valueQuantity"]["value"])
        (coding,) = o["code"]["coding"]
        assert coding["system"] == system and coding["code"] in CODES
        assert o["valueQuantity"]["code"] == CODES[coding["code"]].unit
        site = o["bodySite"]
        assert site["coding"][0]["code"] == "344001"  # SNOMED CT: ankle region structure
        (laterality,) = site["extension"]
        assert laterality["url"] == LATERALITY_EXTENSION
        assert laterality["valueCodeableConcept"]["coding"][0]["code"] == "7771000"  # left

    peaks = sorted(
        o["valueQuantity"]["value"]
        for o in observations
        if o["code"]["coding"][0]["code"] == "peak-angle-plantarflexion"
    )
    assert peaks == pytest.approx([PEAK_DEG, PEAK_DEG * 1.2], abs=1e-3)

    (row,) = await exports(live, world)
    assert row["new"] == {
        "format": "fhir",
        "since": str(first_day),
        "until": str(TODAY),
        "tz": "UTC",
        "sessions": 2,
        "observations": 16,
    }


@pytest.mark.asyncio
async def test_the_code_system_is_served_at_its_canonical_url_and_holds_every_code_used(
    live: Live, world: World
) -> None:
    await two_sessions(live, world)
    system = system_url(live.settings.fhir_base)
    path = system.removeprefix(f"{live.settings.public_url}/api/v1")
    r = await live.client.get(path)  # no token: definitions only
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/fhir+json"
    code_system = CodeSystem.model_validate(r.json())
    assert code_system.url == system and code_system.content == "complete"
    defined = {c.code: c for c in code_system.concept or []}
    assert list(defined) == list(CODES) and code_system.count == len(CODES)
    assert all(c.definition for c in defined.values())

    r = await live.client.get(f"/patients/{world.p1}/fhir", headers=bearer(world.t1))
    used = [
        e["resource"]["code"]["coding"][0]
        for e in r.json()["entry"][1:]  # after the Patient
    ]
    assert used and all(c["system"] == system for c in used)
    for c in used:
        assert defined[c["code"]].display == c["display"]
    patient = r.json()["entry"][0]["resource"]
    assert patient["identifier"][0]["system"] == f"{live.settings.fhir_base}/patient-id"


@pytest.mark.asyncio
async def test_a_direction_never_moved_has_no_mdc95_on_the_progress_or_the_report(
    live: Live, world: World
) -> None:
    """ROM assessments of pitch and roll in which the roll never moved: every roll trial is
    0°, a zero scatter that measures no reliability. Not "MDC95 0.0°" but null with its
    reason, a sentence in the PDF, and no change judged against it."""
    rx = await prescribe(live, world, ExerciseKind.ROM_ASSESSMENT)
    axes = EXERCISE_LIBRARY[ExerciseKind.ROM_ASSESSMENT].defaults.axes
    assert {"pitch", "roll"} <= {a.axis for a in axes}  # the uploads move pitch only
    now = datetime.now(UTC).timestamp()
    for days, trials in ((20, [(20.0, 10.0), (22.0, 12.0)]), (13, [(21.0, 11.0), (23.0, 13.0)])):
        await upload_assessment(
            live, world, assessment_rows(trials), rx, ExerciseKind.ROM_ASSESSMENT, now - days * DAY
        )
    await upload_assessment(
        live,
        world,
        assessment_rows([(25.0, 10.0), (27.0, 12.0)]),
        rx,
        ExerciseKind.ROM_ASSESSMENT,
        now - 6 * DAY,
    )
    t1 = bearer(world.t1)
    p = (await live.client.get(f"/patients/{world.p1}/progress", headers=t1)).json()
    mdc = {(m["axis"], m["sign"]): m for m in p["mdc"]}
    for sign in (1, -1):
        roll = mdc[("roll", sign)]
        assert (roll["mdc95_deg"], roll["sem_deg"], roll["reason"]) == (None, None, "no_scatter")
        assert roll["text"] == "not measurable: never moved this way in 6 trials"
    assert mdc[("pitch", 1)]["mdc95_deg"] == pytest.approx(3.92, abs=1e-3)
    (rom,) = (e for e in p["exercises"] if e["exercise"] == "rom_assessment")
    for m in rom["measures"]:
        if m["axis"] == "roll":
            assert [pt["real_change"] for pt in m["points"]] == [None, None, None], m

    r = await live.client.get(f"/patients/{world.p1}/report.pdf", headers=t1)
    assert r.status_code == 200, r.text
    text = pdf_text(r.content)
    assert "Range of motion against the baseline" in text
    assert text.count("not measurable: never moved this way in 6 trials") == 2, text
    assert "MDC95 0.0" not in text and "beyond MDC95: a real change" in text


@pytest.mark.asyncio
async def test_each_session_download_is_audited_as_an_export_and_not_cached(
    live: Live, world: World
) -> None:
    """A recorded session's files leave the system as the report does: one patient.export
    row per download, naming the session and the format, and Cache-Control: no-store."""
    session_id = await upload(live, world, rows_at(TODAY))
    formats = [*FORMATS, "rec"]
    for fmt in formats:
        r = await live.client.get(
            f"/sessions/{session_id}/download/{fmt}", headers=bearer(world.t1)
        )
        assert r.status_code == 200, (fmt, r.text)
        assert r.headers["cache-control"] == "no-store", fmt
        assert r.content and r.headers["x-content-sha256"], fmt
    again = await live.client.get(
        f"/sessions/{session_id}/download/csv", headers=bearer(world.admin)
    )
    assert again.status_code == 200 and again.headers["cache-control"] == "no-store"
    # Refused, or a format there is none of: nothing left the system, nothing is audited.
    assert (
        await live.client.get(f"/sessions/{session_id}/download/csv", headers=bearer(world.t2))
    ).status_code == 404
    bad = await live.client.get(f"/sessions/{session_id}/download/xls", headers=bearer(world.t1))
    assert bad.status_code == 422

    rows = list(reversed(await exports(live, world)))  # oldest first
    admin_id = (await live.client.get("/auth/me", headers=bearer(world.admin))).json()["id"]
    assert [(r["actor"], r["new"]["format"]) for r in rows] == [
        *((f"user:{world.t1_id}", fmt) for fmt in formats),
        (f"user:{admin_id}", "csv"),
    ]
    for row in rows:
        assert (row["entity"], row["entity_id"], row["patient_id"]) == (
            "session",
            str(session_id),
            world.p1,
        )
        assert row["new"]["session_id"] == session_id and row["old"] is None


@pytest.mark.asyncio
async def test_a_range_download_is_audited_only_when_it_sends_data(
    live: Live, world: World
) -> None:
    """Range past the end (416): nothing left, nothing audited. A part that is sent (206),
    or the whole file because If-Range no longer matches, or because the Range is invalid
    (a part ending before it starts: RFC 9110 lets the server ignore it; it was a 400, the
    sentence of ``bytes=0-0`` wrongly refused), is an export."""
    session_id = await upload(live, world, rows_at(TODAY))
    url, t1 = f"/sessions/{session_id}/download/rec", bearer(world.t1)
    whole = await live.client.get(url, headers=t1)
    assert whole.status_code == 200
    sent = 1
    for ask, status in [
        ({"Range": "bytes=100000000-"}, 416),
        ({"Range": "bytes=5-2"}, 200),
        ({"Range": "bytes=0-1, 5-2"}, 200),
        ({"Range": "bytes=0-0"}, 206),
        ({"Range": "bytes=0-99"}, 206),
        ({"Range": "bytes=100000000-", "If-Range": '"not-this-file"'}, 200),
    ]:
        r = await live.client.get(url, headers={**t1, **ask})
        assert r.status_code == status, (ask, r.text)
        if status == 200:
            assert r.content == whole.content
        if ask["Range"] == "bytes=0-0":
            assert r.content == whole.content[:1]
        sent += status in (200, 206)
        assert len(await exports(live, world)) == sent, ask
    assert r.content == whole.content  # If-Range did not match: the whole file was sent


@pytest.mark.asyncio
async def test_a_range_list_is_served_as_asked_or_refused_never_as_the_whole_file(
    live: Live, world: World
) -> None:
    """A part of a Range list that is not a byte range is malformed (400), as a header that
    is not one at all; more than RANGES_MAX ranges are refused (416). Starlette skipped such a
    part, and past 100 parts ignored the header: ``bytes=0-1,0-1,bytes=0-1,...`` and 300
    one-byte ranges were answered 200 with the whole file, each audited as a full export."""
    session_id = await upload(live, world, rows_at(TODAY))
    url, t1 = f"/sessions/{session_id}/download/rec", bearer(world.t1)
    whole = (await live.client.get(url, headers=t1)).content
    sent = len(await exports(live, world))
    cases = [
        ("bytes=" + "0-1,0-1,bytes=" * 50 + "0-1", 400, "'bytes=0-1' is not a byte range"),
        ("bytes=0-1,abc", 400, "'abc' is not a byte range"),
        ("bytes=0-1,-", 400, "'-' is not a byte range"),
        ("bytes=" + ",".join(f"{i}-{i}" for i in range(300)), 416, "300 ranges; at most 16"),
        ("bytes=" + ",".join(f"{2 * i}-{2 * i}" for i in range(RANGES_MAX + 1)), 416, "17"),
    ]
    for asked, status, says in cases:
        r = await live.client.get(url, headers={**t1, "Range": asked})
        assert r.status_code == status, (asked[:60], r.status_code, r.text[:200])
        assert says in r.text, r.text
        if status == 416:
            assert r.headers["content-range"] == f"bytes */{len(whole)}"
        assert len(await exports(live, world)) == sent, asked[:60]  # nothing was sent
    # What is a list of byte ranges is served as one, empty parts and all (RFC 9110, 5.6.1).
    for asked, parts in [
        ("bytes=0-1,", 1),
        ("bytes= 0-1 , , -2", 2),
        ("bytes=" + ",".join(f"{2 * i}-{2 * i}" for i in range(RANGES_MAX)), RANGES_MAX),
    ]:
        r = await live.client.get(url, headers={**t1, "Range": asked})
        assert r.status_code == 206, (asked[:60], r.text[:200])
        if parts == 1:
            assert r.content == whole[:2]
        else:
            assert r.headers["content-type"].startswith("multipart/byteranges")
            assert r.content.count(b"Content-Range: bytes ") == parts
        sent += 1
        assert len(await exports(live, world)) == sent, asked[:60]


@pytest.mark.asyncio
@pytest.mark.parametrize(
    ("reference", "saved", "plain"),
    [
        ("Řehoř-12", "Řehoř-12", "Rehor-12"),
        ("Ř" * 60, "Ř" * 60, "R" * 60),
        ("王小明", "王小明", "patient-{p}"),
        ("a/b\\c:d", "a-b-c-d", "a-b-c-d"),
    ],
)
async def test_report_and_fhir_names_keep_the_reference_in_its_own_script(
    live: Live, world: World, reference: str, saved: str, plain: str
) -> None:
    """``Řehoř-12`` was saved as ``report-eho--12-…`` and 60 x ``Ř`` as ``report-patient-…``:
    the name is now given as ``filename*`` (RFC 6266/8187), the session downloads' way, with
    an ASCII ``filename`` transliterated where Unicode can."""
    t1 = bearer(world.t1)
    r = await live.client.patch(f"/patients/{world.p1}", json={"reference": reference}, headers=t1)
    assert r.status_code == 200, r.text
    days = f"{TODAY - timedelta(days=89):%Y%m%d}-{TODAY:%Y%m%d}"
    plain = plain.format(p=world.p1)
    for path, suffix in (("report.pdf", ".pdf"), ("fhir", ".fhir.json")):
        r = await live.client.get(f"/patients/{world.p1}/{path}", headers=t1)
        assert r.status_code == 200, r.text
        assert disposition_name(r) == f"report-{saved}-{days}{suffix}"
        assert ascii_fallback(r) == f"report-{plain}-{days}{suffix}"


def text_spans(body: bytes) -> list[tuple[int, str, float, float]]:
    """(page, text, left x, right x) of every piece of text drawn, points: where pypdf finds
    it drawn, its width as the font it is set in measures it."""
    spans: list[tuple[int, str, float, float]] = []
    for number, page in enumerate(PdfReader(io.BytesIO(body)).pages):

        def visit(
            text: str, cm: list[float], tm: list[float], font: Any, size: float, n: int = number
        ) -> None:
            text = text.strip()
            if not text:
                return
            x = cm[0] * tm[4] + cm[2] * tm[5] + cm[4]
            scale = math.hypot(cm[0], cm[1]) * math.hypot(tm[0], tm[1])
            bold = "Bold" in str(font.get("/BaseFont", "")) if font is not None else True
            face = fonts.BOLD if bold else fonts.REGULAR
            width = pdfmetrics.stringWidth(text, face, size * scale)
            spans.append((n, text, x, x + width))

        page.extract_text(visitor_text=visit)
    return spans


@pytest.mark.asyncio
async def test_long_unbroken_text_prints_inside_the_page(live: Live, world: World) -> None:
    """A 120-letter name, title or reference with no space (all allowed by the API): the
    name's cell started 428 pt left of the page, a title 211 pt, and the page footer ran
    to 1075 pt on a 595 pt page. Every piece of text now lies within the page's margins."""
    t1 = bearer(world.t1)
    r = await live.client.patch(
        f"/patients/{world.p1}",
        json={"display_name": "W" * 120, "reference": "Ř" * 64},
        headers=t1,
    )
    assert r.status_code == 200, r.text
    r = await live.client.patch(
        f"/prescriptions/{world.rx1}", json={**STRENGTH, "title": "M" * 120}, headers=t1
    )
    assert r.status_code == 200, r.text
    r = await live.client.get(f"/patients/{world.p1}/report.pdf", headers=t1)
    assert r.status_code == 200, r.text
    spans = text_spans(r.content)
    assert any("WWWW" in t for _, t, _, _ in spans) and any("MMMM" in t for _, t, _, _ in spans)
    left, right = 18 * mm, 595.28 - 18 * mm
    outside = [s for s in spans if s[2] < left - 1 or s[3] > right + 1]
    assert not outside, outside[:5]
    # What was cut to fit is all there, broken across lines (the footer's title aside).
    text = pdf_text(r.content).replace(" ", "")
    assert "W" * 120 in text and "M" * 120 in text and "Ř" * 64 in text


NAMES = ("Łukasz Żółć", "Ελένη Παπαδοπούλου", "Ольга Иванова", "Nguyễn Thị Hằng")
"""Polish, Greek, Russian and Vietnamese: letters Helvetica (WinAnsi) has no glyph for."""


def embedded_fonts(body: bytes) -> set[str]:
    """The fonts the pages use, without their subset prefix ("ABCDEF+DejaVuSans")."""
    out = set()
    for page in PdfReader(io.BytesIO(body)).pages:
        resources: Any = page["/Resources"]
        for font in resources["/Font"].values():
            out.add(str(font.get_object()["/BaseFont"]).split("+")[-1])
    return out


@pytest.mark.asyncio
async def test_names_beyond_western_europe_are_drawn_and_read_back(
    live: Live, world: World
) -> None:
    """Helvetica drew "Łukasz Żółć" with boxes or dropped letters. The report embeds DejaVu
    Sans, which has a glyph for every letter of these names, and its text reads them back."""
    face = None
    for name in NAMES:
        r = await live.client.patch(
            f"/patients/{world.p1}", json={"display_name": name}, headers=bearer(world.t1)
        )
        assert r.status_code == 200, r.text
        r = await live.client.get(f"/patients/{world.p1}/report.pdf", headers=bearer(world.t1))
        assert r.status_code == 200, r.text
        assert name in pdf_text(r.content), name
        assert embedded_fonts(r.content) == {"DejaVuSans", "DejaVuSans-Bold"}, (
            f"set in {fonts.register()}: the server finds DejaVu Sans on the system "
            "(fonts-dejavu-core) or in matplotlib"
        )
        face = face or pdfmetrics.getFont(fonts.REGULAR).face  # registered by the server
        missing = [c for c in name if c != " " and ord(c) not in face.charToGlyph]
        assert not missing, (name, missing)


@pytest.mark.asyncio
async def test_an_empty_period_gives_a_valid_report_saying_so(live: Live, world: World) -> None:
    t1 = bearer(world.t1)
    r = await live.client.get(f"/patients/{world.p1}/report.pdf", headers=t1)
    assert r.status_code == 200, r.text
    text = pdf_text(r.content)
    assert "No sessions in this period." in text and "0 sessions in the period" in text
    assert "No faults, holds or early ends in this period." in text
    r = await live.client.get(f"/patients/{world.p1}/fhir", headers=t1)
    body = r.json()
    Bundle.model_validate(body)
    assert [e["resource"]["resourceType"] for e in body["entry"]] == ["Patient"]


@pytest.mark.asyncio
async def test_another_therapists_patient_is_not_found_and_nothing_is_audited(
    live: Live, world: World
) -> None:
    for path in ("report.pdf", "fhir"):
        r = await live.client.get(f"/patients/{world.p1}/{path}", headers=bearer(world.t2))
        assert r.status_code == 404, path
        assert r.json() == {"detail": "patient not found"}
    assert await exports(live, world) == []


@pytest.mark.parametrize(
    ("params", "field", "words"),
    [
        (
            {"since": "2026-13-01"},
            "since",
            "the first day (since) must be a date written YYYY-MM-DD",
        ),
        ({"until": "yesterday"}, "until", "the last day (until) must be a date written YYYY-MM-DD"),
        # An ISO week or the basic format: Python reads them as days, the sentence asks not.
        ({"since": "2025-W50"}, "since", "the first day (since) must be a date written"),
        ({"since": "20251207"}, "since", "the first day (since) must be a date written"),
        ({"until": "9999-12-31"}, "until", "between 1900-01-01 and 9998-12-31"),
        ({"since": "2026-03-02", "until": "2026-03-01"}, "since", "the period must start"),
        # A signed report headed "to 2099-12-31" would claim days still to come.
        ({"since": "2026-01-01", "until": "2099-12-31"}, "until", "2099-12-31, is still to come"),
        # A zone the server does not know, its own clock's (whichever that is), or a name
        # longer than any file name (an OSError inside zoneinfo, not a 500).
        ({"tz": "Mars/Olympus_Mons"}, "tz", "an IANA time zone name such as Europe/Berlin"),
        ({"tz": "localtime"}, "tz", "got 'localtime'"),
        ({"tz": "Europe/" + "x" * 300}, "tz", "such as Europe/Berlin or UTC; got 'Europe/xxx"),
    ],
)
@pytest.mark.asyncio
async def test_a_bad_period_is_a_422_with_a_sentence(
    live: Live, world: World, params: dict[str, str], field: str, words: str
) -> None:
    for path in ("report.pdf", "fhir"):
        r = await live.client.get(
            f"/patients/{world.p1}/{path}", params=params, headers=bearer(world.t1)
        )
        assert r.status_code == 422, (path, r.text)
        (error,) = r.json()["detail"]
        assert error["loc"] == ["query", field]
        assert words in error["msg"]
    assert await exports(live, world) == []


@pytest.mark.asyncio
async def test_a_period_ends_today_wherever_the_therapist_is(live: Live, world: World) -> None:
    """The page sends the therapist's own date, a day ahead of UTC's for part of every day
    east of Greenwich: the latest day begun anywhere (UTC+14) is taken; a later one is
    refused with that day named as the latest (the next day's, if it began meanwhile)."""
    latest = (datetime.now(UTC) + timedelta(hours=14)).date()
    t1 = bearer(world.t1)
    r = await live.client.get(
        f"/patients/{world.p1}/fhir", params={"until": str(latest)}, headers=t1
    )
    assert r.status_code == 200, r.text
    later = latest + timedelta(days=2)
    r = await live.client.get(
        f"/patients/{world.p1}/fhir", params={"until": str(later)}, headers=t1
    )
    assert r.status_code == 422, r.text
    (error,) = r.json()["detail"]
    assert error["loc"] == ["query", "until"]
    assert error["msg"] in {
        f"the last day (until), {later}, is still to come: a report covers days that have "
        f"begun, up to today ({day} at the latest)"
        for day in (latest, latest + timedelta(days=1))
    }
    assert len(await exports(live, world)) == 1  # the accepted one only


@pytest.mark.asyncio
async def test_a_named_zone_ends_the_period_on_its_own_today(live: Live, world: World) -> None:
    """Kiritimati (UTC+14) is always a day or two ahead of Pago Pago (UTC-11): its today is
    taken without a zone (some clock has begun it) but not as a day of Pago Pago's."""
    ahead = datetime.now(ZoneInfo("Pacific/Kiritimati")).date()
    t1, path = bearer(world.t1), f"/patients/{world.p1}/fhir"
    r = await live.client.get(path, params={"until": str(ahead)}, headers=t1)
    assert r.status_code == 200, r.text
    r = await live.client.get(
        path, params={"until": str(ahead), "tz": "Pacific/Pago_Pago"}, headers=t1
    )
    assert r.status_code == 422, r.text
    (error,) = r.json()["detail"]
    assert error["loc"] == ["query", "until"] and "is still to come" in error["msg"]


LATE = datetime(2025, 12, 7, 23, 59, 50, tzinfo=UTC)
"""A session begun ten seconds before midnight UTC: 8 December in Berlin, the evening of the
7th in New York."""


async def upload_at(live: Live, world: World, at: datetime) -> None:
    await upload(live, world, samples()[:3000], started_at=at.timestamp())


async def report_text(live: Live, world: World, params: dict[str, str]) -> str:
    r = await live.client.get(
        f"/patients/{world.p1}/report.pdf", params=params, headers=bearer(world.t1)
    )
    assert r.status_code == 200, r.text
    return pdf_text(r.content)


async def fhir_starts(live: Live, world: World, params: dict[str, str]) -> set[str]:
    """The start of every observation's effectivePeriod in the bundle of ``params``."""
    r = await live.client.get(f"/patients/{world.p1}/fhir", params=params, headers=bearer(world.t1))
    assert r.status_code == 200, r.text
    return {
        e["resource"]["effectivePeriod"]["start"]
        for e in r.json()["entry"]
        if e["resource"]["resourceType"] == "Observation"
    }


@pytest.mark.parametrize(
    ("tz", "day", "row", "header"),
    [
        ("Europe/Berlin", "2025-12-08", "2025-12-08 00:59", "Europe/Berlin (UTC+01:00)"),
        (None, "2025-12-07", "2025-12-07 23:59", "UTC (UTC+00:00)"),
        ("UTC", "2025-12-07", "2025-12-07 23:59", "UTC (UTC+00:00)"),
        ("America/New_York", "2025-12-07", "2025-12-07 18:59", "America/New_York (UTC-05:00)"),
    ],
)
@pytest.mark.asyncio
async def test_a_day_is_the_therapists_own_in_the_report_and_the_bundle(
    live: Live, world: World, tz: str | None, day: str, row: str, header: str
) -> None:
    """The report page sends the therapist's calendar day and zone: a session shows on the
    day their dashboard shows it, at their clock's time, and only on that day."""
    await upload_at(live, world, LATE)
    zone = {} if tz is None else {"tz": tz}
    other = str(date.fromisoformat(day) + timedelta(days=1 if day.endswith("07") else -1))
    before = datetime.now(ZoneInfo(tz or "UTC")).date()
    text = await report_text(live, world, {"since": day, "until": day, **zone})
    after = datetime.now(ZoneInfo(tz or "UTC")).date()
    assert "1 session in the period" in text, text
    assert any(f"Generated {d}" in text for d in (before, after)), text  # the zone's today
    assert f"times are in {header}." in text, text
    sessions = text[text.index("Date Exercise Ended") :]
    assert row in sessions, sessions
    text = await report_text(live, world, {"since": other, "until": other, **zone})
    assert "0 sessions in the period" in text, text

    # FHIR: the same day holds its observations, stamped with an ISO 8601 offset.
    (start,) = await fhir_starts(live, world, {"since": day, "until": day, **zone})
    assert datetime.fromisoformat(start) == LATE and start.endswith("+00:00"), start
    assert await fhir_starts(live, world, {"since": other, "until": other, **zone}) == set()


@pytest.mark.asyncio
async def test_a_day_that_changes_to_summer_time_is_23_hours_of_its_zone(
    live: Live, world: World
) -> None:
    """Berlin's 29 March 2026 runs from 00:00 UTC+01:00 to 24:00 UTC+02:00 (22:00 UTC); a
    fixed UTC+01:00 would end it at 23:00 UTC and take in 00:30 of the 30th. A time past the
    change names its offset, the header naming the day's first."""
    for at in ("2026-03-28T23:30:00Z", "2026-03-29T21:30:00Z", "2026-03-29T22:30:00Z"):
        await upload_at(live, world, datetime.fromisoformat(at))
    params = {"since": "2026-03-29", "until": "2026-03-29", "tz": "Europe/Berlin"}
    text = await report_text(live, world, params)
    assert "2 sessions in the period" in text, text
    assert "times are in Europe/Berlin (UTC+01:00)." in text, text
    sessions = text[text.index("Date Exercise Ended") : text.index("Progress over the period")]
    assert "2026-03-29 00:30" in sessions and "2026-03-29 23:30 UTC+02:00" in sessions, sessions
    assert "2026-03-30" not in sessions, sessions
    starts = await fhir_starts(live, world, params)
    assert starts == {"2026-03-28T23:30:00+00:00", "2026-03-29T21:30:00+00:00"}


def test_directions_follow_the_affected_side() -> None:
    """Roll's directions swap between a left and a right foot; pitch's do not."""
    axis = AxisSummary(
        rom_min_deg=-8.0,
        rom_max_deg=12.0,
        rom_deg=20.0,
        peak_torque_nm=5.0,
        mean_torque_nm=2.0,
        work_j=1.5,
        tracking_error_rms_deg=None,
        time_in_target_pct=None,
    )
    summary = Summary(
        duration_s=60.0,
        elapsed_s=70.0,
        samples=7000,
        sets_completed=1,
        repetitions_completed=3,
        repetitions_prescribed=3,
        end_reason="completed",
        axes={"roll": axis, "pitch": axis},
        events={},
        faults=[],
    )

    def peaks(side: str | None) -> dict[str, float]:
        return {m.code.code: m.value for m in measures(summary, side) if m.direction is not None}

    assert peaks("right") == {
        "peak-angle-inversion": 12.0,
        "peak-angle-eversion": 8.0,
        "peak-angle-plantarflexion": 12.0,
        "peak-angle-dorsiflexion": 8.0,
    }
    assert peaks("left")["peak-angle-eversion"] == 12.0
    assert peaks("both")["peak-angle-left-edge-up"] == 12.0


def test_the_code_system_is_documented() -> None:
    """docs/measures.md carries the whole code system, as generated."""
    doc = (ROOT / "docs" / "measures.md").read_text()
    assert "{fhir_base}/CodeSystem/session-measures" in doc
    assert code_table_markdown() in doc


def test_a_column_is_never_narrower_than_its_longest_word() -> None:
    """DejaVu Sans is wider than Helvetica: at the widths laid out for Helvetica, "Per week"
    ran into "Prescribed", the date into the exercise and "interrupted" broke in two. Each
    column now takes the room its longest word needs from columns that have some to spare."""
    fonts.register()  # as pdf() does: alone, this test had no report made before it
    header = ["Date", "Exercise", "Ended", "Repetitions", "Measures"]
    rows = [["2026-11-15 12:00", "Strength (resistive)", "interrupted", "3 of 30", "x " * 80]]
    wanted = [26 * mm, 24 * mm, 20 * mm, 20 * mm, 80 * mm]
    table = report._table(header, rows, wanted)
    widths = table._colWidths
    assert sum(widths) == pytest.approx(sum(wanted))  # the table keeps its designed width
    for i, column in enumerate(zip(header, *rows, strict=True)):
        for j, text in enumerate(column):
            font = fonts.BOLD if j == 0 else fonts.REGULAR
            for word in text.split():
                assert pdfmetrics.stringWidth(word, font, 8) + 12 <= widths[i] + 1e-6, word
    # Slack comes from the columns that have it; a table whose words need more than all
    # of it grows rather than cut a word.
    assert report.fit_widths([10, 50], [30, 20]) == pytest.approx([30, 30])
    assert report.fit_widths([10, 10], [30, 20]) == [30, 20]
    assert report.fit_widths([40, 40], [10, 10]) == [40, 40]
    # Never past the page: the widest needs are cut to one level, the narrow ones kept.
    assert report.fit_widths([10, 10], [300, 20], 100) == pytest.approx([80, 20])
    assert report.fit_widths([10, 10, 10], [300, 200, 20], 100) == pytest.approx([40, 40, 20])


@pytest.mark.parametrize(
    ("gaps", "missing_s", "listed"),
    [
        (
            2,
            40.4,
            ["telemetry missing for 40 s (2 gaps): the session's numbers leave that time out"],
        ),
        (3, 0.12, []),  # a few frames lost on the wire: counted, not notable
        (None, None, []),  # a summary stored before gaps were counted
    ],
)
def test_telemetry_missing_is_a_notable_event(
    gaps: int | None, missing_s: float | None, listed: list[str]
) -> None:
    from sessions.record import Session as RecordedSession

    summary: dict[str, Any] = {"faults": [], "events": {}}
    if gaps is not None:
        summary |= {"telemetry_gaps": gaps, "telemetry_missing_s": missing_s}
    s = RecordedSession(1, "u", datetime.now(UTC), None, "completed", None, "strength", summary)
    assert report.notable_events(s) == listed
