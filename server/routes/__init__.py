"""The REST routes. To add a group, write its module and append its router to ``ROUTERS``:
``create_app`` mounts each under ``API_PREFIX``."""

from __future__ import annotations

from fastapi import APIRouter

from server.routes import (
    audit,
    auth,
    exercises,
    fhir,
    health,
    home_station,
    patients,
    prescriptions,
    progress,
    reports,
    sessions,
    stations,
    uploads,
    users,
)

API_PREFIX = "/api/v1"

ROUTERS: list[APIRouter] = [
    health.router,
    auth.router,
    users.router,
    patients.router,
    exercises.router,
    prescriptions.router,
    stations.router,
    home_station.router,
    sessions.router,
    reports.router,
    fhir.router,
    progress.router,
    uploads.router,
    audit.router,
]
