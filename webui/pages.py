"""The therapist dashboard's pages, served by the server under ``/app``.

Each page is a static HTML file and one script module that talks to ``/api/v1`` with the
therapist's bearer token, so every page works against the same API a script would use.
"""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import FileResponse, RedirectResponse

from server.deps import Id
from webui.assets import STATIC, page

router = APIRouter(include_in_schema=False)


@router.get("/")
async def root() -> RedirectResponse:
    return RedirectResponse("/app/patients")


@router.get("/favicon.ico")
async def favicon() -> FileResponse:
    return FileResponse(STATIC / "favicon.svg", media_type="image/svg+xml")


@router.get("/app")
@router.get("/app/")
async def app_root() -> RedirectResponse:
    return RedirectResponse("/app/patients")


@router.get("/app/login")
async def login() -> FileResponse:
    return page("login.html")


@router.get("/app/patients")
async def patients() -> FileResponse:
    return page("patients.html")


@router.get("/app/patients/{patient_id}")
async def patient(patient_id: Id) -> FileResponse:
    return page("patient.html")


@router.get("/app/patients/{patient_id}/prescribe")
async def prescribe(patient_id: Id) -> FileResponse:
    return page("prescribe.html")


@router.get("/app/live/{station_id}")
async def live(station_id: Id) -> FileResponse:
    return page("live.html")


@router.get("/app/sessions/{session_id}")
async def session(session_id: Id) -> FileResponse:
    return page("session.html")


@router.get("/app/password")
async def password() -> FileResponse:
    return page("password.html")


@router.get("/app/accounts")
async def accounts() -> FileResponse:
    return page("accounts.html")
