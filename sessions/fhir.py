"""A patient's sessions as a FHIR R4 ``Bundle`` (type ``collection``) for the medical record.

One ``Patient`` and, per session, one ``Observation`` per measure (:mod:`sessions.measures`):
the value as a UCUM ``Quantity`` (``deg``, ``N.m``, ``J``, ``s``), the session's start and
end as ``effectivePeriod``, the ankle as ``bodySite`` (SNOMED CT 344001 *Ankle region
structure*) with the patient's affected side as the standard laterality extension (SNOMED CT
7771000 left, 24028007 right, 51440002 right and left), category ``therapy``, and the
project's own code (no standard code names these measures), whose code system
:func:`code_system` gives as a FHIR ``CodeSystem`` resource. Observations of a passive
range-of-motion session also carry SNOMED CT 710830005 *Assessment of passive range of
motion* as their method; an active ROM assessment has no such standard code, and gets none.

Every name of the project's own is under the site's base URL (the server's ``fhir_base``):
the code system ``{site}/CodeSystem/session-measures``, the identifier systems
``{site}/patient-id`` and ``{site}/observation-id``. A patient number means something only
on the server that gave it, and a canonical URL must be under a domain its publisher holds.

Every id is a name-based UUID of the site, the session and the code, so exporting the same
period twice gives the same resources. Plain JSON out; the tests validate it with
``fhir.resources``' R4B models (R4B keeps R4's Patient, Observation and Bundle).
"""

from __future__ import annotations

import uuid
from datetime import datetime
from typing import Any, Final

from sessions.measures import CODE_SYSTEM_ID, CODES, UCUM, Measure, system_url
from sessions.record import Patient, PatientRecord, Session

MEDIA_TYPE: Final = "application/fhir+json"
SNOMED: Final = "http://snomed.info/sct"
LATERALITY_EXTENSION: Final = (
    "http://hl7.org/fhir/StructureDefinition/observation-structureLaterality"
)
ANKLE: Final = {"system": SNOMED, "code": "344001", "display": "Ankle region structure"}
LATERALITY: Final[dict[str, dict[str, str]]] = {
    "left": {"system": SNOMED, "code": "7771000", "display": "Left"},
    "right": {"system": SNOMED, "code": "24028007", "display": "Right"},
    "both": {"system": SNOMED, "code": "51440002", "display": "Right and left"},
}
PASSIVE_ROM_ASSESSMENT: Final = {
    "system": SNOMED,
    "code": "710830005",
    "display": "Assessment of passive range of motion",
}
THERAPY: Final = {
    "system": "http://terminology.hl7.org/CodeSystem/observation-category",
    "code": "therapy",
    "display": "Therapy",
}


def patient_id_system(site: str) -> str:
    """Identifier system of the server's own patient number."""
    return f"{site.rstrip('/')}/patient-id"


def observation_id_system(site: str) -> str:
    """Identifier system of an observation: ``<session uuid>/<code>``."""
    return f"{site.rstrip('/')}/observation-id"


def _urn(site: str, *parts: object) -> str:
    name = "/".join([site.rstrip("/"), *map(str, parts)])
    return f"urn:uuid:{uuid.uuid5(uuid.NAMESPACE_URL, name)}"


def _instant(t: datetime) -> str:
    return t.isoformat(timespec="seconds")


def body_site(side: str | None) -> dict[str, Any]:
    """The ankle, with the side as laterality when it is known."""
    site: dict[str, Any] = {"coding": [ANKLE]}
    lat = LATERALITY.get(side or "")
    if lat is None:
        site["text"] = "Ankle"
        return site
    site["text"] = f"{lat['display']} ankle"
    site["extension"] = [{"url": LATERALITY_EXTENSION, "valueCodeableConcept": {"coding": [lat]}}]
    return site


def patient_resource(site: str, p: Patient) -> dict[str, Any]:
    resource: dict[str, Any] = {
        "resourceType": "Patient",
        "id": _urn(site, "patient", p.id).removeprefix("urn:uuid:"),
        "identifier": [{"system": patient_id_system(site), "value": str(p.id)}],
        "name": [{"text": p.display_name}],
    }
    if p.reference:
        resource["identifier"].append({"use": "usual", "value": p.reference})
    if p.birth_year is not None:
        resource["birthDate"] = f"{p.birth_year:04d}"
    return resource


def observation(
    site: str, record: PatientRecord, session: Session, m: Measure, subject: str
) -> dict[str, Any]:
    period = {"start": _instant(session.started_at)}
    if session.ended_at is not None:
        period["end"] = _instant(session.ended_at)
    obs: dict[str, Any] = {
        "resourceType": "Observation",
        "id": _urn(site, session.uuid, m.code.code).removeprefix("urn:uuid:"),
        "identifier": [
            {"system": observation_id_system(site), "value": f"{session.uuid}/{m.code.code}"}
        ],
        "status": "final",
        "category": [{"coding": [THERAPY]}],
        "code": {
            "coding": [
                {"system": system_url(site), "code": m.code.code, "display": m.code.display}
            ],
            "text": m.label,
        },
        "subject": {"reference": subject},
        "effectivePeriod": period,
        "issued": _instant(record.generated_at),
        "valueQuantity": {
            "value": round(m.value, 3),
            "unit": m.code.unit,
            "system": UCUM,
            "code": m.code.unit,
        },
        "bodySite": body_site(record.patient.affected_side),
    }
    if session.exercise == "passive_rom":
        obs["method"] = {"coding": [PASSIVE_ROM_ASSESSMENT]}
    return obs


def bundle(site: str, record: PatientRecord) -> dict[str, Any]:
    """The record as a FHIR R4 collection Bundle (JSON-ready), its own names under ``site``."""
    patient = patient_resource(site, record.patient)
    subject = f"urn:uuid:{patient['id']}"
    entries = [{"fullUrl": subject, "resource": patient}]
    for s in record.sessions:
        for m in record.measures(s):
            obs = observation(site, record, s, m, subject)
            entries.append({"fullUrl": f"urn:uuid:{obs['id']}", "resource": obs})
    return {
        "resourceType": "Bundle",
        "id": _urn(
            site, "bundle", record.patient.id, _instant(record.since), _instant(record.until)
        ).removeprefix("urn:uuid:"),
        "type": "collection",
        "timestamp": _instant(record.generated_at),
        "entry": entries,
    }


def code_system(site: str) -> dict[str, Any]:
    """The session-measure code system as a FHIR R4 ``CodeSystem`` resource (JSON-ready),
    complete: every code with its display, definition and UCUM unit (as the property
    ``unit``). The server serves it at its own canonical URL."""
    return {
        "resourceType": "CodeSystem",
        "id": CODE_SYSTEM_ID,
        "url": system_url(site),
        "name": "SessionMeasures",
        "title": "Ankle rehabilitation session measures",
        "status": "active",
        "experimental": False,
        "description": "What one session on the ankle rehabilitation platform measured: "
        "peak angles in each direction of the patient's foot, ranges of motion, torques, "
        "work and exercise time. Angles are degrees from the platform's home pose.",
        "caseSensitive": True,
        "content": "complete",
        "count": len(CODES),
        "property": [
            {
                "code": "unit",
                "description": "The UCUM unit of the measure's value",
                "type": "string",
            }
        ],
        "concept": [
            {
                "code": c.code,
                "display": c.display,
                "definition": c.definition,
                "property": [{"code": "unit", "valueString": c.unit}],
            }
            for c in CODES.values()
        ],
    }
