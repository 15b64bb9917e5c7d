"""Live links: home stations and therapists' live views over WebSocket (being written)."""

from __future__ import annotations

from fastapi import APIRouter

router = APIRouter()


class Hub:
    """Connected stations and their viewers, in one process."""

    def __init__(self) -> None:
        self._online: set[int] = set()

    def online(self, station_id: int) -> bool:
        return station_id in self._online

    async def prescriptions_changed(self, station_id: int) -> None:
        """Tell a connected station that its patient's prescriptions changed."""

    async def close(self) -> None:
        """Close every live connection (at shutdown)."""
