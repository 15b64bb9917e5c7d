from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from server.deps import TherapistOrAdmin
from server.models import Side
from server.routes.common import UNAUTHORIZED
from sessions.bounds import PrescriptionLimits, prescription_limits
from sessions.prescription import EXERCISE_LIBRARY, ExerciseTemplate

router = APIRouter(prefix="/exercises", tags=["prescriptions"])


@router.get(
    "",
    response_model=list[ExerciseTemplate],
    summary="The exercise library",
    responses=UNAUTHORIZED,
)
async def list_exercises(user: TherapistOrAdmin) -> list[ExerciseTemplate]:
    """Each exercise with its purpose and default settings: a new prescription is usually
    one of these defaults, adjusted."""
    return list(EXERCISE_LIBRARY.values())


@router.get(
    "/limits",
    response_model=PrescriptionLimits,
    summary="What a prescription may ask",
    responses=UNAUTHORIZED,
)
async def exercise_limits(
    user: TherapistOrAdmin,
    side: Annotated[
        Side | None,
        Query(description="The patient's affected side: names roll and yaw directions for it."),
    ] = None,
) -> PrescriptionLimits:
    """Each axis's allowed range (anatomy and the device, the narrower), the device's stable
    stiffness–damping envelope (the values its HELLO publishes), each number field's bounds
    with the sentence a value past them is refused with, and each axis's directions named
    for the affected side."""
    return prescription_limits(side)
