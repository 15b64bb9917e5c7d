"""The station's settings: one object, read from ``ANKLE_STATION_*`` environment variables
(``ANKLE_STATION_TOKEN``, ``ANKLE_STATION_SERVER``…) like the server's ``ANKLE_*``; a command
line option given to ``ankle station`` overrides its variable.

Every rule on a value is here, once: the command line reports a refusal in one line naming
the option (``--hold-limit 0 is not a time from more than 0 to 3600 s``).
"""

from __future__ import annotations

import math
from pathlib import Path

from pydantic import Field, field_validator
from pydantic_core import PydanticCustomError
from pydantic_settings import BaseSettings, SettingsConfigDict

from sessions.wire import BATCH_HZ, BATCH_HZ_MAX
from station.reasons import HOLD_LIMIT_S

HOLD_LIMIT_MAX_S = 3600.0


class StationConfig(BaseSettings):
    """Where the device and the server are, who this station is, and how it runs."""

    model_config = SettingsConfigDict(env_prefix="ANKLE_STATION_", extra="ignore")

    device: str = Field(
        default="", description="The platform's serial link: a port, a pty name or socket://H:P."
    )
    server: str = Field(default="", description="The server's URL, e.g. http://clinic:8000.")
    token: str = Field(default="", repr=False, description="This station's token.")
    spool: Path = Field(
        default=Path("ankle-station"), description="Directory for sessions waiting to upload."
    )
    baud: int = Field(default=921600, gt=0)
    autostart: bool = Field(
        default=False,
        description="Start the first active prescription once connected (the demo; and a "
        "patient's station set to start at a fixed time).",
    )
    repeat_after_s: float | None = Field(
        default=None,
        description="With autostart: start it again this long after each session that "
        "finished whole (the demo). A stop, from anyone, ends the repeats until the next start.",
    )
    hold_limit_s: float = Field(
        default=HOLD_LIMIT_S,
        description="An exercise held (paused, HOLD, or held by the device) this long is "
        "ended: the platform goes home and the session closes 'interrupted' with the reason.",
    )
    batch_hz: float = Field(
        default=BATCH_HZ,
        description="Telemetry messages a second to the server, each with the samples since "
        "the last.",
    )
    page_port: int = Field(default=8765, description="The patient's page's port; 0: no page.")
    page_host: str = Field(
        default="127.0.0.1", description="Address the patient's page listens on."
    )

    @field_validator("device", "server", "token")
    @classmethod
    def _given(cls, value: str) -> str:
        if not value.strip():
            raise PydanticCustomError("station", "is required")
        return value

    @field_validator("hold_limit_s")
    @classmethod
    def _hold_limit(cls, value: float) -> float:
        if not 0 < value <= HOLD_LIMIT_MAX_S:  # also refuses nan
            raise PydanticCustomError(
                "station",
                f"{value:g} is not a time from more than 0 to {HOLD_LIMIT_MAX_S:g} s",
            )
        return value

    @field_validator("repeat_after_s")
    @classmethod
    def _repeat(cls, value: float | None) -> float | None:
        if value is not None and not (value > 0 and math.isfinite(value)):
            raise PydanticCustomError("station", f"{value:g} is not a time of more than 0 s")
        return value

    @field_validator("batch_hz")
    @classmethod
    def _batch(cls, value: float) -> float:
        if not 1 <= value <= BATCH_HZ_MAX:  # also refuses nan
            raise PydanticCustomError(
                "station",
                f"{value:g} is not a rate from 1 to {BATCH_HZ_MAX:g} messages a second",
            )
        return value

    @field_validator("page_port")
    @classmethod
    def _port(cls, value: int) -> int:
        if not 0 <= value <= 65535:
            raise PydanticCustomError("station", f"{value} is not a port (0..65535)")
        return value
