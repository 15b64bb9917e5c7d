"""The site's own FHIR definitions, served at their canonical URLs (the default
``fhir_base`` is this router's path), so a record system that meets one of the project's
codes in an exported Bundle can look up what it means."""

from __future__ import annotations

import json

from fastapi import APIRouter, Request, Response

from sessions import fhir
from sessions.measures import CODE_SYSTEM_ID

router = APIRouter(prefix="/fhir", tags=["fhir"])


@router.get(
    f"/CodeSystem/{CODE_SYSTEM_ID}",
    response_class=Response,
    summary="The session-measure code system as a FHIR R4 CodeSystem",
    responses={
        200: {
            "content": {fhir.MEDIA_TYPE: {}},
            "description": "Every code the FHIR export uses that no standard code system "
            "has, with its display, definition and UCUM unit.",
        }
    },
)
async def session_measures(request: Request) -> Response:
    """No authentication: definitions only, nothing about any patient. Its ``url`` is the
    site's canonical one (``fhir_base``), whether or not that is this address."""
    body = fhir.code_system(request.app.state.settings.fhir_base)
    return Response(
        json.dumps(body, ensure_ascii=False),
        media_type=fhir.MEDIA_TYPE,
        headers={"Cache-Control": "public, max-age=3600"},
    )
