"""OpenAPI descriptions of the error answers every route shares."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fastapi import FastAPI
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute, iter_route_contexts
from pydantic import BaseModel

from server.deps import MUST_CHANGE_PASSWORD, current_user


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


def _depends_on(dependant: Dependant, call: Callable[..., Any]) -> bool:
    return any(d.call is call or _depends_on(d, call) for d in dependant.dependencies)


def document_must_change(app: FastAPI) -> None:
    """Publish, on every operation that ``server.deps.current_user`` guards, the 403 it
    answers a user who must change their password first; generated from the routes'
    dependencies when the document is built, so that no route, present or future, is
    missed and the few that let such a user in (change password, me, logout) do not list
    it."""
    build = app.openapi
    done: set[int] = set()  # the documents already amended (FastAPI rebuilds on new routes)

    def openapi() -> dict[str, Any]:
        schema = build()
        if id(schema) in done:
            return schema
        sentence = f"the user must change their password first: '{MUST_CHANGE_PASSWORD}'."
        for context in iter_route_contexts(app.routes):
            route = context.original_route
            if not isinstance(route, APIRoute) or not _depends_on(route.dependant, current_user):
                continue
            operations = schema["paths"].get(context.path_format or "", {})
            for method in route.methods or ():
                if method.lower() not in operations:
                    continue  # not in the document (include_in_schema=False)
                responses = operations[method.lower()]["responses"]
                answer = responses.setdefault("403", {"description": "", "content": _ERROR_BODY})
                before = answer["description"]
                answer["description"] = f"{before} Or {sentence}" if before else "T" + sentence[1:]
        done.add(id(schema))
        return schema

    app.openapi = openapi  # type: ignore[method-assign]


_ERROR_BODY = {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorPublic"}}}
