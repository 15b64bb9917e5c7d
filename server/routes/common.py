"""OpenAPI descriptions of the error answers every route shares."""

from __future__ import annotations

import hashlib
import re
import unicodedata
from collections.abc import Callable
from pathlib import Path
from typing import Any
from urllib.parse import quote

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


_NOT_IN_NAME = re.compile(r"[^\w.-]+")
_NOT_ASCII_NAME = re.compile(r"[^A-Za-z0-9._-]+")


def name_part(text: str) -> str:
    """``text`` as part of a file name, in any script: letters, digits, ``.``, ``_`` and
    ``-`` kept (composed, NFC), every other run (blanks, slashes, punctuation) one ``-``."""
    return _NOT_IN_NAME.sub("-", unicodedata.normalize("NFC", text)).strip("-.")


def ascii_name(text: str) -> str:
    """``text`` in ASCII for a client that reads only ``filename=``: transliterated where
    Unicode can (``Řehoř`` -> ``Rehor``: NFKD, combining marks dropped), then every other
    run one ``-``; empty if nothing of it is ASCII."""
    decomposed = unicodedata.normalize("NFKD", text)
    letters = "".join(c for c in decomposed if not unicodedata.combining(c))
    return _NOT_ASCII_NAME.sub("-", letters).strip("-.")


def attachment(name: str, fallback: str | None = None) -> str:
    """The ``Content-Disposition`` of a download saved as ``name`` (RFC 6266): a name in
    plain ASCII as ``filename``, any other as ``filename*=UTF-8''…`` (RFC 8187) with
    ``fallback`` (by default :func:`ascii_name` of it) as ``filename`` for clients that
    read only that. Session downloads, the report and the FHIR bundle all use it."""
    if _NOT_ASCII_NAME.search(name) is None:
        return f'attachment; filename="{name}"'
    plain = fallback if fallback is not None else ascii_name(name)
    return f"attachment; filename=\"{plain}\"; filename*=UTF-8''{quote(name, safe='')}"


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


def file_sha256(path: Path) -> str:
    """The SHA-256 of a file, read a megabyte at a time (a recording may be tens of MB)."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()
