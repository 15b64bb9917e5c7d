"""The exercise library a prescription starts from."""

from __future__ import annotations

from fastapi import APIRouter

from server.deps import TherapistOrAdmin
from server.routes.common import UNAUTHORIZED
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
