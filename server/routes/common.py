"""OpenAPI descriptions of the error answers every route shares."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel


class ErrorPublic(BaseModel):
    detail: str


Responses = dict[int | str, dict[str, Any]]
"""The type of FastAPI's ``responses=`` argument; merge with ``{**A, **B}``."""


def _err(description: str) -> dict[str, Any]:
    return {"model": ErrorPublic, "description": description}


UNAUTHORIZED: Responses = {401: _err("Token missing, unknown, expired or revoked.")}
FORBIDDEN: Responses = {403: _err("The caller's role may not do this.")}
NOT_FOUND: Responses = {404: _err("No such record, or it belongs to another therapist's patient.")}
CONFLICT: Responses = {409: _err("The record's state does not allow this change.")}
