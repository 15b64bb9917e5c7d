"""What the patient's page and its station say to each other over ``/ws``.

Down go what the page shows: today's exercises (:class:`Today`, on connecting and when the
therapist changes them), the station's state in the patient's terms (:class:`PageStatus`, on
every change and at least once a second) and the foot's angles for the game (:class:`Foot`,
~30 Hz). Up come the patient's actions (:data:`PageAction`): start, pause, resume, stop and
the game's score. Each is validated; a malformed one is answered with :class:`PageError` and
changes nothing.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, model_validator

from sessions import wire
from webui.home.game import GameField

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)


# -- down: station to page -------------------------------------------------------------------
class Exercise(BaseModel):
    model_config = _STRICT
    id: wire.Id
    title: str
    instructions: str
    exercise: str
    sets: int
    repetitions: int
    repetition_s: float
    rest_s: float
    minutes: int = Field(description="About how long it takes, rests included.")
    game: GameField | None = Field(description="None: no game in this exercise.")


class Today(BaseModel):
    model_config = _STRICT
    type: Literal["today"] = "today"
    exercises: list[Exercise]


class PageStatus(BaseModel):
    """The station's state as the page shows it."""

    model_config = _STRICT
    type: Literal["status"] = "status"
    online: bool = Field(description="The therapist's server is reachable.")
    pending_uploads: int = Field(description="Sessions saved here, waiting to be sent.")
    refused_uploads: int = Field(
        default=0,
        description="Sessions the therapist's server refused: kept here, not sent again.",
    )
    device: Literal["connected", "lost"]
    device_mode: str
    phase: wire.Phase
    session_id: str | None
    prescription_id: wire.Id | None
    set: int
    rep: int
    sets: int
    repetitions: int
    sets_done: int
    reps_done: int
    rest_remaining_s: float
    message: str
    link_lost: bool = Field(
        default=False,
        description="The last exercise ended because the station lost the platform's link "
        "(phase interrupted): not because it was held too long.",
    )
    starts_again_at: float | None = Field(
        default=None,
        description="The demo starts its exercise again by itself at this time (UNIX "
        "seconds); None when nothing will start without the patient.",
    )
    hold: wire.HoldInfo | None = Field(
        description="Why the platform holds: the patient's own pause, or something else that "
        "only the therapist (or the station's limit) ends."
    )
    supply_low: bool = Field(
        description="The device says the platform's air supply is low (its telemetry's "
        "SUPPLY_LOW flag): nothing starts or carries on until it is back.",
    )


class Foot(BaseModel):
    """The foot's angles now, degrees from home (pitch > 0: toes down; roll > 0: the foot's
    left edge up)."""

    model_config = _STRICT
    type: Literal["foot"] = "foot"
    pitch: float
    roll: float


class YourProgress(BaseModel):
    """The patient's own progress in a few plain sentences (from the therapist's server; not
    sent while the station has never reached it)."""

    model_config = _STRICT
    type: Literal["progress"] = "progress"
    lines: list[str]


class ActionResult(BaseModel):
    model_config = _STRICT
    type: Literal["result"] = "result"
    id: str | None = None
    action: str
    ok: bool
    text: str = Field(default="", description="Why not, in plain words.")


class PageError(BaseModel):
    model_config = _STRICT
    type: Literal["error"] = "error"
    text: str


# -- up: page to station ---------------------------------------------------------------------
_Id = Annotated[str | None, Field(default=None, max_length=64)]
_Count = Annotated[int, Field(ge=0, le=100_000)]


class Start(BaseModel):
    model_config = _STRICT
    type: Literal["start"]
    id: _Id = None
    prescription_id: wire.Id


class Pause(BaseModel):
    model_config = _STRICT
    type: Literal["pause"]
    id: _Id = None


class Resume(BaseModel):
    model_config = _STRICT
    type: Literal["resume"]
    id: _Id = None


class Stop(BaseModel):
    model_config = _STRICT
    type: Literal["stop"]
    id: _Id = None


class GameScore(BaseModel):
    """The game's running totals after a gate: recorded in the session it was played in."""

    model_config = _STRICT
    type: Literal["game_score"]
    id: _Id = None
    session_id: str = Field(min_length=1, max_length=64)
    game: int = Field(ge=1, le=2**31, description="Tells apart two games in one session.")
    score: _Count = Field(description="Gates flown through.")
    gates: _Count = Field(description="Gates that came up.")
    missed: _Count = Field(description="Gates missed.")

    @model_validator(mode="after")
    def _adds_up(self) -> GameScore:
        if self.score + self.missed != self.gates:
            raise ValueError("score + missed must equal gates")
        return self


PageAction = Annotated[Start | Pause | Resume | Stop | GameScore, Field(discriminator="type")]
PAGE_ACTION: TypeAdapter[Start | Pause | Resume | Stop | GameScore] = TypeAdapter(PageAction)
PageMessage = Annotated[
    Today | PageStatus | Foot | YourProgress | ActionResult | PageError,
    Field(discriminator="type"),
]


def page_schemas() -> dict[str, Any]:
    """The JSON Schema of each direction of ``/ws``, served at ``/schemas``."""
    return {
        "page_to_station": PAGE_ACTION.json_schema(),
        "station_to_page": TypeAdapter(PageMessage).json_schema(),
    }
