"""API routes that need the 3D view (viser): they live here because only webui imports it."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request
from pydantic import BaseModel, Field

from server.deps import Db, TherapistOrAdmin, patient_for
from server.models import Station
from server.routes.common import NOT_FOUND, UNAUTHORIZED
from webui.live3d import IDLE_S, LiveScenes

router = APIRouter(tags=["live"], responses=UNAUTHORIZED)


class ScenePublic(BaseModel):
    station_id: int
    port: int = Field(description="TCP port of the station's viser server on this host.")
    path: str = Field(description="Path and query to open, e.g. in an iframe.")
    idle_s: float = Field(description="The view stops after this long unwatched, s.")
    updates: int = Field(description="Telemetry samples drawn since the view started.")
    platform_position: list[float] = Field(
        description="Where the scene draws the ankle frame now: x, y, z in m (world frame)."
    )
    platform_wxyz: list[float] = Field(description="Its orientation, a unit quaternion.")


@router.get(
    "/stations/{station_id}/scene",
    response_model=ScenePublic,
    responses=NOT_FOUND,
    summary="The live 3D view of a station",
)
async def station_scene(
    station_id: int, request: Request, db: Db, user: TherapistOrAdmin
) -> ScenePublic:
    """Starts the station's viser view if it is not running and says where it is: open
    ``http://<this server's host>:<port><path>``. It follows the station's telemetry at
    30 Hz and stops once nobody has watched it (live WebSocket or this call) for a while."""
    station = await db.get(Station, station_id)
    if station is None:
        raise HTTPException(404, "station not found")
    try:
        await patient_for(db, user, station.patient_id)
    except HTTPException:
        raise HTTPException(404, "station not found") from None
    scenes: LiveScenes = request.app.state.scenes
    view = await scenes.open(station_id)
    platform = view.scene.platform
    return ScenePublic(
        station_id=station_id,
        port=view.port,
        path="/",
        idle_s=IDLE_S,
        updates=view.scene.updates,
        platform_position=[float(v) for v in platform.position],
        platform_wxyz=[float(v) for v in platform.wxyz],
    )
