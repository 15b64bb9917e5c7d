"""What the REST API reads and writes: role-suffixed pydantic models.

``XCreate`` is a request body that makes an X, ``XUpdate`` one that changes it, ``XPublic``
what the API returns. ORM rows never leave the server as they are: a password or token hash
has no ``Public`` field to leak through. Prescriptions reuse ``sessions.prescription``'s
``PrescriptionBody``, the one model the station runs, rather than a copy of it.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    StringConstraints,
    ValidationInfo,
    computed_field,
    field_validator,
    model_validator,
)

from server.models import Prescription, PrescriptionStatus, Role, Side, Station
from server.security import (
    PASSWORD_MAX_LENGTH,
    PASSWORD_MIN_LENGTH,
    PASSWORD_SCORE_MIN,
    password_weakness,
)
from sessions.anatomy import direction_table
from sessions.prescription import AxisPrescription, PrescriptionBody, PrescriptionInput
from sessions.sentences import FieldError, field_label, setting_parts
from sessions.text import (
    EMAIL_MAX_LENGTH,
    EMAIL_PATTERN,
    Line,
    Lines,
    email_address,
    sign_in_address,
    visible_name,
)

Email = Annotated[
    str,
    StringConstraints(strip_whitespace=True),
    AfterValidator(email_address),  # length and shape once NFKC-normal: "ｔａ＠x" is "ta@x"
    Field(
        description="Login name; stored NFKC-normalised and lower-case (sessions.text).",
        examples=["therapist@clinic.example"],
        json_schema_extra={"maxLength": EMAIL_MAX_LENGTH, "pattern": EMAIL_PATTERN},
    ),
]
Password = Annotated[
    str,
    Field(
        min_length=PASSWORD_MIN_LENGTH,
        max_length=PASSWORD_MAX_LENGTH,
        description=f"At least {PASSWORD_MIN_LENGTH} characters, not easy to guess (zxcvbn "
        f"score {PASSWORD_SCORE_MIN} of 4 at least, the account's e-mail and name counted as "
        "known; judged on the first 72 characters); a passphrase is best.",
    ),
]
Name = Annotated[
    str,
    StringConstraints(strip_whitespace=True, min_length=1, max_length=120),
    AfterValidator(visible_name),  # after the strip: a pasted name's trailing line break is dropped
]


def _not_in_future(year: int | None) -> int | None:
    if year is not None and year > datetime.now(UTC).year:
        raise ValueError(f"Birth year {year} is in the future.")
    return year


BirthYear = Annotated[
    int | None,
    Field(ge=1900, description="Year of birth (age matters for normal ranges), 1900..now."),
    AfterValidator(_not_in_future),
]

WEIGHT_KG_MIN, WEIGHT_KG_MAX = 10.0, 400.0
WeightKg = Annotated[
    float | None,
    Field(
        ge=WEIGHT_KG_MIN,
        le=WEIGHT_KG_MAX,
        allow_inf_nan=False,
        title="Body weight",
        json_schema_extra={"unit": "kg"},
        description=f"Body weight, kg ({WEIGHT_KG_MIN:g}..{WEIGHT_KG_MAX:g}), optional: torque "
        "is also shown per kilogram of body weight where it is known.",
    ),
]

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)
_FROM_ORM = ConfigDict(from_attributes=True)


# --- auth and users ---------------------------------------------------------------------


class LoginRequest(BaseModel):
    model_config = _STRICT

    email: Annotated[str, AfterValidator(sign_in_address)] = Field(
        max_length=EMAIL_MAX_LENGTH, description="The account's email address."
    )
    password: str = Field(max_length=PASSWORD_MAX_LENGTH)


class UserCreate(BaseModel):
    model_config = _STRICT

    email: Email
    name: Name = Field(description="Shown in the dashboard and the audit log.")
    role: Role = Field(description="therapist: own patients; admin: users, stations, audit.")
    password: Password | None = Field(
        default=None,
        description="Leave out (the usual case): the server makes a one-time password, "
        "answers it once, and its owner must change it at the first sign-in. Give one only "
        "when the account's owner chose it themselves.",
    )

    @model_validator(mode="after")
    def _hard_to_guess(self) -> UserCreate:
        if self.password is not None:
            weak = password_weakness(self.password, (self.email, self.name))
            if weak is not None:
                raise FieldError(("password",), weak)
        return self


class UserPublic(BaseModel):
    model_config = _FROM_ORM

    id: int
    email: str
    name: str
    role: Role
    active: bool = Field(description="An inactive (deactivated) account cannot log in.")
    must_change_password: bool = Field(
        description="The password was printed or reset: until its owner changes it "
        "(POST /auth/password), their sign-in may only change it, read /auth/me and log out."
    )
    created_at: datetime


class UserCreated(UserPublic):
    one_time_password: str | None = Field(
        description="The password the server made, shown this once (null when the request "
        "gave one). Hand it to the account's owner, who must change it at the first sign-in."
    )


class PasswordReset(BaseModel):
    user: UserPublic
    one_time_password: str = Field(
        description="The account's new password, shown this once; its owner must change it "
        "at the next sign-in. Every login of the account has ended."
    )


class PasswordChange(BaseModel):
    model_config = _STRICT

    current_password: str = Field(
        max_length=PASSWORD_MAX_LENGTH, description="The password this account signs in with now."
    )
    new_password: Password

    @field_validator("new_password")
    @classmethod
    def _new_differs(cls, value: str, info: ValidationInfo) -> str:
        if value == info.data.get("current_password"):
            raise ValueError("the new password must differ from the current one")
        return value


class TokenPublic(BaseModel):
    access_token: str = Field(description="Send as 'Authorization: Bearer <token>'.")
    token_type: Literal["bearer"] = "bearer"
    expires_at: datetime = Field(description="UTC; log in again after it.")
    user: UserPublic = Field(
        description="Who signed in; with user.must_change_password, the token serves only "
        "to change the password (POST /auth/password), /auth/me and logging out."
    )


# --- patients ---------------------------------------------------------------------------


class PatientCreate(BaseModel):
    model_config = _STRICT

    display_name: Name = Field(
        description="How the therapist and the patient's station name "
        "the patient (initials or a first name suffice)."
    )
    reference: Line | None = Field(
        default=None, max_length=64, description="The clinic's own identifier, if any."
    )
    birth_year: BirthYear = None
    affected_side: Side | None = Field(default=None, description="The ankle being treated.")
    weight_kg: WeightKg = None
    notes: Lines = Field(default="", max_length=5000, description="Free text for the therapist.")


_REQUIRED_ON_UPDATE = ("display_name", "notes")


class PatientUpdate(BaseModel):
    """Only the fields present change; ``null`` clears an optional field."""

    model_config = _STRICT

    display_name: Name | None = None
    reference: Line | None = Field(default=None, max_length=64)
    birth_year: BirthYear = None
    affected_side: Side | None = None
    weight_kg: WeightKg = None
    notes: Lines | None = Field(default=None, max_length=5000)

    @model_validator(mode="after")
    def _no_null_for_required(self) -> PatientUpdate:
        for name in _REQUIRED_ON_UPDATE:
            if name in self.model_fields_set and getattr(self, name) is None:
                label = field_label(name, type(self).model_fields[name])
                raise FieldError((name,), f"{label} cannot be empty.")
        return self


class PatientPublic(BaseModel):
    model_config = _FROM_ORM

    id: int
    therapist_id: int = Field(description="The user whose patient this is.")
    display_name: str
    reference: str | None
    birth_year: int | None
    affected_side: Side | None
    weight_kg: float | None = Field(description="Body weight, kg; null when not recorded.")
    notes: str
    created_at: datetime
    updated_at: datetime
    archived_at: datetime | None = Field(
        description="When the therapist archived the patient (read-only, left out of the "
        "default list), UTC; null for a current patient."
    )

    @computed_field(  # type: ignore[prop-decorator]
        description="Each axis's direction names and labels for the affected side "
        "(sessions.anatomy.direction_table): what a page calls sign 1 ('positive') and -1."
    )
    @property
    def directions(self) -> dict[str, dict[str, str]]:
        return direction_table(self.affected_side)


class PatientArchived(PatientPublic):
    """What archiving did besides marking the record."""

    stations_revoked: list[int] = Field(
        description="Ids of the patient's stations revoked now: their tokens are refused and "
        "their live links closed (the devices go back to the clinic)."
    )
    prescriptions_cancelled: list[int] = Field(
        description="Ids of the active prescriptions withdrawn now."
    )


# --- prescriptions ----------------------------------------------------------------------


class PrescriptionCreate(PrescriptionInput):
    """A new prescription: an exercise from GET /exercises with its settings and timeline.
    Checked against anatomical ranges and the device's limits; a 422 names field and bound."""


class PrescriptionUpdate(PrescriptionInput):
    """The whole new body of an active prescription; the version goes up by one."""


class AxisImpedanceText(BaseModel):
    """One axis's K and B in the words of the forms and their sentences (sessions.sentences)."""

    axis: str
    stiffness: str = Field(description='K per radian: "40 N·m/rad".')
    stiffness_per_degree: str = Field(description='The same K per degree: "0.698 N·m/°".')
    damping: str = Field(description='B per radian: "2 N·m·s/rad".')
    damping_per_degree: str = Field(description='The same B per degree: "0.0349 N·m·s/°".')

    @classmethod
    def of(cls, a: AxisPrescription) -> AxisImpedanceText:
        k, k_deg = setting_parts(a, "stiffness")
        b, b_deg = setting_parts(a, "damping")
        assert k_deg is not None and b_deg is not None  # both are per radian
        return cls(
            axis=a.axis,
            stiffness=k,
            stiffness_per_degree=k_deg,
            damping=b,
            damping_per_degree=b_deg,
        )


class PrescriptionPublic(BaseModel):
    id: int
    patient_id: int
    created_by: int = Field(description="The user who wrote the prescription.")
    status: PrescriptionStatus = Field(
        description="active: the station runs it; cancelled: withdrawn by the therapist; "
        "completed: all its sessions done."
    )
    version: int = Field(ge=1, description="1 on creation, +1 on each update.")
    created_at: datetime
    updated_at: datetime
    total_s: float = Field(description="Exercise time including rests between sets, s.")
    body: PrescriptionBody
    impedance_text: list[AxisImpedanceText] = Field(
        description="Each axis's K and B (in body.axes' order) per radian and per degree, as "
        "the forms write them."
    )

    @classmethod
    def from_row(cls, row: Prescription) -> PrescriptionPublic:
        body = PrescriptionBody.model_validate(row.body)
        return cls(
            id=row.id,
            patient_id=row.patient_id,
            created_by=row.created_by,
            status=row.status,  # type: ignore[arg-type]  # the column's CHECK keeps it valid
            version=row.version,
            created_at=row.created_at,
            updated_at=row.updated_at,
            total_s=body.total_s(),
            body=body,
            impedance_text=[AxisImpedanceText.of(a) for a in body.axes],
        )


# --- stations ---------------------------------------------------------------------------


class StationCreate(BaseModel):
    model_config = _STRICT

    name: Name = Field(description="Where the station is, e.g. 'Home, living room'.")


class StationPublic(BaseModel):
    model_config = _FROM_ORM

    id: int
    patient_id: int
    name: str
    created_at: datetime
    last_seen_at: datetime | None = Field(description="Last request or connection, UTC.")
    revoked: bool = Field(description="A revoked station's token is refused.")
    online: bool = Field(default=False, description="Connected to the live link now.")

    @classmethod
    def from_row(cls, row: Station, online: bool) -> StationPublic:
        return cls.model_validate(row).model_copy(update={"online": online})


class StationProvisioned(StationPublic):
    token: str = Field(
        description="The station's bearer token. Shown once, never stored in clear: put it in "
        "the station's configuration now; if lost, revoke and provision again."
    )


class StationSelf(BaseModel):
    """What a station learns about itself with its own token."""

    id: int
    name: str
    patient_id: int
    patient_display_name: str


# --- audit, health ----------------------------------------------------------------------


class AuditPublic(BaseModel):
    model_config = _FROM_ORM

    id: int
    at: datetime
    actor: str = Field(description="'user:<id>', 'station:<id>' or 'system'.")
    action: str = Field(
        description="'<entity>.<verb>', e.g. 'prescription.update'; a live command: "
        "'hold.request' then 'hold.accepted', 'hold.refused' or 'hold.unanswered' (K/B: "
        "'impedance.request', then 'impedance.change' only when the device accepted it)."
    )
    entity: str
    entity_id: str
    patient_id: int | None
    old: dict[str, Any] | None = Field(description="Changed fields before; null on creation.")
    new: dict[str, Any] | None = Field(description="Changed fields after.")


class HealthPublic(BaseModel):
    status: Literal["ok", "degraded"]
    version: str = Field(description="The server's package version.")
    database: bool = Field(description="The database answered a query.")
    relay: bool | None = Field(
        default=None,
        description="The relay between server processes (ANKLE_RELAY_URL) answered; null "
        "without one. Down, live links between processes are lost.",
    )
    login_throttle_storage: bool | None = Field(
        default=None,
        description="The shared store of failed sign-ins (ANKLE_LOGIN_THROTTLE_STORAGE) "
        "answered; null when they are counted in this process. Down, every sign-in is "
        "refused (503).",
    )
    disk_free_bytes: int = Field(description="Free space where the data directory is, bytes.")
    disk_ok: bool = Field(description="At least the configured minimum of it is free.")
    audit_backlog: int = Field(
        default=0,
        description="Live audit rows waiting for the database (a HOLD or Stop never waits "
        "for it): written in order once it answers, 0 normally. Not a reason for a restart: "
        "they are held in this process's memory.",
    )
