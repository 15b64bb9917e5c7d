"""The server's settings: one object, read from ``ANKLE_*`` environment variables.

Nothing here is read at import time: ``create_app(Settings(...))`` gets its own copy, so tests
and the one-machine demo run servers side by side on different data directories.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from limits import parse
from pydantic import Field, SecretStr, ValidationError, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict
from pydantic_settings import SettingsError as PydanticSettingsError

from server.audit import BACKLOG_MAX
from server.logs import LogFormat
from server.throttle import open_storage
from server.tickets import TICKET_TTL_S

MiB = 1024 * 1024
_WILDCARD_HOSTS = {"0.0.0.0", "::", ""}


class Settings(BaseSettings):
    """Where the server keeps its data, where it listens and how long credentials last.

    Every field can be set as ``ANKLE_<FIELD>`` (``ANKLE_DATA_DIR=/srv/ankle``); lists are JSON
    (``ANKLE_ALLOWED_ORIGINS='["https://clinic.example"]'``). Fields whose default depends on
    another field (the database URL on ``data_dir``, the origins and public URL on ``host`` and
    ``port``) are filled in when the object is built, so reading them never gives ``None``.
    """

    model_config = SettingsConfigDict(env_prefix="ANKLE_", extra="ignore")

    data_dir: Path = Field(
        default=Path("ankle-data"),
        description="Directory for the SQLite database, uploaded sessions and the demo's "
        "credentials file; created on start.",
    )
    database_url: str = Field(
        default="",
        description="SQLAlchemy async URL. Empty or unset: "
        "sqlite+aiosqlite:///{data_dir}/ankle.db. PostgreSQL: "
        "postgresql+asyncpg://user:password@host/db (the `postgres` install extra).",
    )
    migrate_on_start: bool = Field(
        default=True,
        description="Bring the database's schema up to date when the server starts (under a "
        "lock, so several processes may start at once). False where a DBA runs `ankle db "
        "upgrade` and the server's role may not change the schema: the server then refuses "
        "to start on a schema that is not current.",
    )
    host: str = Field(default="127.0.0.1", description="Interface to listen on.")
    log_format: LogFormat = Field(
        default="text",
        description="'text': uvicorn's lines, for people; 'json': one JSON object a line with "
        "request_id (HTTP) and link_id (live links), for a log collector.",
    )
    metrics_token: SecretStr | None = Field(
        default=None,
        description="Unset: /metrics answers loopback clients only. Set: it answers anyone "
        "sending 'Authorization: Bearer <token>', and no one else.",
    )
    port: int = Field(default=8000, ge=0, le=65535, description="TCP port; 0 picks a free one.")
    keep_alive_s: int = Field(
        default=75,
        gt=0,
        le=3600,
        description="How long an idle HTTP connection stays open for the client's next "
        "request, seconds. Longer than any client or proxy in front keeps it idle: whoever "
        "closes an idle connection must be the client, or a request sent as the server "
        "closes it is lost ('server disconnected without sending a response', a 502 behind "
        "a proxy). httpx gives up idle connections after 5 s and the deploy/ samples' "
        "proxies after 60 s; browsers keep theirs longer but send again a request that a "
        "reused connection closed on unanswered. uvicorn's own default is 5 s.",
    )
    header_timeout_s: float = Field(
        default=30.0,
        gt=0,
        le=3600,
        description="How long a client may take to send a request's headers, from their "
        "first byte, seconds; the connection is closed after it (server.protocols). A "
        "client or proxy sends them at once; one that trickles them holds a connection "
        "for nothing. A new connection that sends nothing is closed after keep_alive_s.",
    )
    body_timeout_s: float = Field(
        default=60.0,
        gt=0,
        le=3600,
        description="How long a request's body may go without a byte while the server reads "
        "it, seconds; answered 408 and the connection closed after it (server.protocols). "
        "The time between two reads, not the whole body's, as nginx's client_body_timeout "
        "(whose default it is): a station's 1 MiB chunk over a slow link arrives in many "
        "reads, and its own client gives up a write that makes no progress for 30 s.",
    )
    allowed_origins: list[str] = Field(
        default_factory=list,
        description="Browser origins allowed to call the API and open WebSockets. Empty: "
        "http://127.0.0.1:{port} and http://localhost:{port}, the server's own pages.",
    )
    token_ttl_s: int = Field(
        default=12 * 3600,
        gt=0,
        le=30 * 24 * 3600,
        description="Lifetime of a therapist's or admin's login token, seconds (a clinic shift).",
    )
    live_recheck_s: float = Field(
        default=30.0,
        gt=0,
        le=3600,
        description="How often open live links re-check their credentials even when this "
        "process changed none (a change made in the database directly, or by another server "
        "process), seconds. Changes made through this server close the links at once.",
    )
    gc_freeze: bool = Field(
        default=True,
        description="Once started, move everything made so far out of the garbage "
        "collector's reach and collect the young generation less often "
        "(server.app.settle_garbage_collector): full collections that walked the whole "
        "start-up stopped the live relay for 90-145 ms. Off only where many servers start "
        "in one long-lived process (the tests).",
    )
    relay_url: str = Field(
        default="",
        description="Where server processes share live links: empty for one process alone "
        "(the embedded default); redis://host:port/db for a Redis that every server process "
        "of the site uses, so a station and its viewers may be on different processes.",
    )
    relay_lease_s: float = Field(
        default=10.0,
        gt=0.0,
        le=300.0,
        description="With a relay: a station stays online this long after its server process "
        "stopped answering (a lease refreshed every third of it), seconds.",
    )
    audit_backlog_max: int = Field(
        default=BACKLOG_MAX,
        ge=1,
        description="Audit rows of live commands kept in memory, in order, while the database "
        "is away (a HOLD or Stop never waits for it); they are written when it is back. Past "
        "it a row is not kept: it is logged in full at ERROR and counted in /metrics "
        "(ankle_audit_rows_lost_total), and a K/B change, Resume or Start is refused.",
    )
    view_ticket_ttl_s: float = Field(
        default=TICKET_TTL_S,
        gt=0.0,
        le=3600.0,
        description="How long a ticket to open a live 3D view works unused, seconds; a view "
        "open on it keeps it alive.",
    )
    upload_max_bytes: int = Field(
        default=512 * MiB,
        gt=0,
        description="Largest session file a station may upload, bytes.",
    )
    upload_expire_s: float = Field(
        default=86400.0,
        gt=0.0,
        description="An incomplete upload no chunk has reached for this long is abandoned: "
        "its bytes and its row are removed at start and by a pass every "
        "min(upload_expire_s / 4, 1 hour), seconds. The station keeps its own copy and "
        "sends it again from the start.",
    )
    body_max_bytes: int = Field(
        default=1 * MiB,
        gt=0,
        description="Largest JSON request body, bytes; a larger one is refused (413) before "
        "anything reads it. Upload chunks have their own limit.",
    )
    disk_free_min_bytes: int = Field(
        default=512 * MiB,
        ge=0,
        description="Below this much free space in data_dir, /health answers 503 'degraded'.",
    )
    login_account_limit: str = Field(
        default="10 per 15 minutes",
        description="Failed sign-ins allowed per account in a moving window (the limits "
        "library's notation); past it, 429 with Retry-After.",
    )
    login_address_limit: str = Field(
        default="30 per 15 minutes",
        description="Failed sign-ins allowed per client address in a moving window.",
    )
    login_delay_max_s: float = Field(
        default=4.0,
        ge=0.0,
        le=60.0,
        description="Longest delay before a sign-in is checked; delays double with each "
        "failure past the first third of a limit.",
    )
    login_pending_max: int = Field(
        default=4,
        ge=1,
        description="Sign-ins of one account or one address in progress at once; more get 429.",
    )
    login_throttle_storage: str = Field(
        default="memory://",
        description="Where failed sign-ins are counted: memory:// is this process; "
        "redis://host:6379/db (or rediss://, redis+unix://, redis+cluster://, "
        "redis+sentinel://) shares the counts between server processes.",
    )
    password_hash_concurrency: int = Field(
        default=2,
        ge=1,
        le=64,
        description="Argon2 hashes computed at once (each takes ~64 MiB and a core for "
        "~0.1 s); more sign-ins wait their turn.",
    )
    export_workers: int = Field(
        default=1,
        ge=1,
        le=8,
        description="Session downloads made at once, each in a process of its own (a core and "
        "up to about 3x the recording's size in memory while it runs); more wait their turn.",
    )
    export_queue_max: int = Field(
        default=8,
        ge=1,
        le=1000,
        description="Session downloads being made or waiting to be; past this a new one is "
        "refused with 503 and Retry-After.",
    )
    export_timeout_s: float = Field(
        default=1800.0,
        gt=0,
        le=86400,
        description="Seconds a session download may take to make before it is stopped (503).",
    )
    public_url: str = Field(
        default="",
        description="Base URL people and stations use to reach this server (behind a reverse "
        "proxy: its https:// address, whose origin is then also allowed). Empty: "
        "http://{host}:{port}, with 127.0.0.1 for a wildcard host.",
    )
    fhir_base: str = Field(
        default="",
        description="Base URL of this site's own FHIR names: the session-measure code system "
        "is {fhir_base}/CodeSystem/session-measures, patient numbers are identified by "
        "{fhir_base}/patient-id. A URL under a domain the clinic holds; set it once before "
        "the first export and never change it (records already exported carry it). Empty: "
        "{public_url}/api/v1/fhir, where this server serves the code system.",
    )

    @field_validator("login_account_limit", "login_address_limit")
    @classmethod
    def _rate(cls, value: str) -> str:
        try:
            parse(value)
        except ValueError:
            raise ValueError(
                f"{value!r} is not a rate such as '10 per 15 minutes' or '30/hour'"
            ) from None
        return value

    @field_validator("fhir_base")
    @classmethod
    def _fhir_base(cls, value: str) -> str:
        if not _is_base_url(value):
            raise ValueError(
                f"{value!r} is not a base URL such as https://records.clinic.example/fhir"
            )
        return value

    @field_validator("public_url")
    @classmethod
    def _public_url(cls, value: str) -> str:
        if not _is_base_url(value):
            raise ValueError(f"{value!r} is not a base URL such as https://ankle.clinic.example")
        return value

    @field_validator("allowed_origins")
    @classmethod
    def _origins(cls, value: list[str]) -> list[str]:
        if "*" in value:
            # The API's CORS would take it, but a live link's handshake compares origins
            # as written (server.live.origin_ok): every browser's view would be refused.
            raise ValueError(
                '"*" is not an origin: list each origin the pages are loaded from, such as '
                '["https://ankle.clinic.example"]'
            )
        return value

    @field_validator("data_dir")
    @classmethod
    def _data_dir(cls, value: Path) -> Path:
        for path in (value, *value.absolute().parents):
            if path.exists():  # the nearest that does: a directory, or nothing can be made
                if not path.is_dir():
                    raise ValueError(f"{path} is a file, not a directory")
                break
        return value

    @field_validator("login_throttle_storage")
    @classmethod
    def _counts(cls, value: str) -> str:
        open_storage(value)  # its ValueError names what works
        return value

    @field_validator("database_url")
    @classmethod
    def _database(cls, value: str) -> str:
        scheme = urlsplit(value).scheme.lower()
        if scheme == "sqlite+aiosqlite":
            return value
        if scheme != "postgresql+asyncpg":
            # The scheme alone: the URL may hold a password, and this reaches the log.
            raise ValueError(
                f"{scheme or 'no'} scheme is not a database the server runs on: use "
                "postgresql+asyncpg://user:password@host/db, or nothing for SQLite in the "
                "data directory"
            )
        if importlib.util.find_spec("asyncpg") is None:
            raise ValueError(
                "PostgreSQL needs the asyncpg driver, which is not installed: install the "
                "server with its postgres extra"
            )
        return value

    @field_validator("relay_url")
    @classmethod
    def _relay(cls, value: str) -> str:
        scheme = urlsplit(value).scheme.lower()
        if value and scheme not in ("redis", "rediss", "unix"):
            # The scheme alone: the URL may hold a password, and this reaches the log.
            raise ValueError(
                f"{scheme or 'no'} scheme is not a relay: use redis://host:port/db, or nothing"
            )
        return value

    @model_validator(mode="before")
    @classmethod
    def _derived_defaults(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        data = dict(data)
        data_dir = Path(data.get("data_dir") or "ankle-data")
        host = str(data.get("host") or "127.0.0.1")
        try:
            port = int(data.get("port") if data.get("port") is not None else 8000)
        except (TypeError, ValueError):
            port = 8000  # for the defaults below; the port's own check names ANKLE_PORT
        if not data.get("database_url"):
            data["database_url"] = f"sqlite+aiosqlite:///{data_dir / 'ankle.db'}"
        public = str(data.get("public_url") or "")
        if not data.get("allowed_origins"):
            local = [f"http://127.0.0.1:{port}", f"http://localhost:{port}"]
            # Behind a reverse proxy the pages are loaded from the public address.
            data["allowed_origins"] = [_origin(public), *local] if public else local
        if not public:
            shown = "127.0.0.1" if host in _WILDCARD_HOSTS else host
            if ":" in shown:
                shown = f"[{shown}]"
            data["public_url"] = public = f"http://{shown}:{port}"
        if not data.get("fhir_base"):
            # routes.fhir serves it. From a public URL that is not one, nothing: its own
            # check names ANKLE_PUBLIC_URL, and this one must not blame ANKLE_FHIR_BASE.
            base = public.rstrip("/") if _is_base_url(public) else "http://127.0.0.1"
            data["fhir_base"] = f"{base}/api/v1/fhir"
        data["fhir_base"] = str(data["fhir_base"]).rstrip("/")
        return data

    @property
    def is_sqlite(self) -> bool:
        return self.database_url.startswith("sqlite")


class SettingsError(ValueError):
    """Settings that cannot work: one line naming each wrong ``ANKLE_*`` variable."""


def load_settings(**overrides: Any) -> Settings:
    """``Settings(**overrides)`` for the command line: a setting that cannot work is a
    SettingsError in one line (which variable, what is wrong, what works), where pydantic's
    own report is several lines that quote the value, which may hold a password."""
    try:
        return Settings(**overrides)
    except PydanticSettingsError as exc:  # a list or object that is not JSON
        field = re.search(r'field "(\w+)"', str(exc))
        name = f"ANKLE_{field.group(1).upper()}" if field else "an ANKLE_* variable"
        raise SettingsError(
            f'{name}: not JSON; a list is written as JSON, such as ["https://clinic.example"]'
        ) from None
    except ValidationError as exc:
        wrong = []
        for error in exc.errors():
            name = "_".join(str(part) for part in error["loc"]).upper()
            text = str(error["msg"]).removeprefix("Value error, ")
            wrong.append(f"ANKLE_{name}: {text}" if name else text)
        raise SettingsError("; ".join(wrong)) from None


def _is_base_url(url: str) -> bool:
    """An http(s) URL with a host and no query: what a base URL setting must be."""
    parts = urlsplit(url)
    return parts.scheme in ("http", "https") and bool(parts.netloc) and not parts.query


def _origin(url: str) -> str:
    """The browser origin of ``url``: scheme, host and port (no path)."""
    parts = urlsplit(url.strip())
    return f"{parts.scheme}://{parts.netloc}"
