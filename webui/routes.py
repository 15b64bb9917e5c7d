"""API routes that need the 3D view (viser): they live here because only webui imports it."""

from __future__ import annotations

from fastapi import APIRouter, Request
from pydantic import BaseModel, Field

from server.deps import Db, Id, TherapistOrAdmin, UserCredentials, record_for
from server.models import Station, User
from server.routes.common import NOT_FOUND, UNAUTHORIZED
from server.tickets import ViewTickets
from webui.live3d import IDLE_S, LiveScenes
from webui.sceneproxy import STATION, scene_path

router = APIRouter(tags=["live"], responses=UNAUTHORIZED)


class ScenePublic(BaseModel):
    station_id: int
    idle_s: float = Field(description="The view stops after this long unwatched, s.")
    updates: int = Field(description="Telemetry samples drawn since the view started.")
    platform_position: list[float] = Field(
        description="Where the scene draws the ankle frame now: x, y, z in m (world frame)."
    )
    platform_wxyz: list[float] = Field(description="Its orientation, a unit quaternion.")


class SceneTicketPublic(BaseModel):
    station_id: int
    path: str = Field(
        description="Path on this server of the 3D view, e.g. for an iframe: it holds the ticket."
    )
    expires_s: float = Field(
        description="The ticket works for this long, s, and for as long as a view is open on it."
    )


async def _watchable(db: Db, user: User, station_id: int) -> Station:
    """The station whose live view ``user`` may watch: the live view's rule (their patient's,
    or any for an admin); else the same 404 as for a station that does not exist."""
    return await record_for(db, user, Station, station_id, "station")


@router.get(
    "/stations/{station_id}/scene",
    response_model=ScenePublic,
    responses=NOT_FOUND,
    summary="The live 3D view of a station: what it draws",
)
async def station_scene(
    station_id: Id, request: Request, db: Db, user: TherapistOrAdmin
) -> ScenePublic:
    """Starts the station's 3D view if it is not running and says what it draws now. It
    follows the station's telemetry at 30 Hz and stops once nobody has watched it (live
    WebSocket, 3D client or this call) for a while. Open it with a ticket
    (``POST .../scene/ticket``)."""
    await _watchable(db, user, station_id)
    scenes: LiveScenes = request.app.state.scenes
    view = await scenes.open(station_id)
    platform = view.scene.platform
    return ScenePublic(
        station_id=station_id,
        idle_s=IDLE_S,
        updates=view.scene.updates,
        platform_position=[float(v) for v in platform.position],
        platform_wxyz=[float(v) for v in platform.wxyz],
    )


@router.post(
    "/stations/{station_id}/scene/ticket",
    response_model=SceneTicketPublic,
    responses=NOT_FOUND,
    summary="A ticket to open the live 3D view of a station",
)
async def station_scene_ticket(
    station_id: Id,
    request: Request,
    db: Db,
    user: TherapistOrAdmin,
    credentials: UserCredentials,
) -> SceneTicketPublic:
    """A ticket for this user and this station only, in the path to open (on this server's
    own port, e.g. in an iframe): a frame cannot send the bearer token. It works for
    ``expires_s`` and for as long as a 3D client stays connected on it."""
    await _watchable(db, user, station_id)
    tickets: ViewTickets = request.app.state.view_tickets
    assert credentials is not None  # the user was authenticated by it
    ticket = tickets.issue(user.id, (STATION, station_id), login=credentials.credentials)
    await request.app.state.hub.share_ticket(ticket)  # the page may load from another process
    return SceneTicketPublic(
        station_id=station_id, path=scene_path(ticket), expires_s=tickets.ttl_s
    )
