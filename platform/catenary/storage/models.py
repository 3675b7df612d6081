"""SQLAlchemy models of the catenary database (the storage sketch of DESIGN.md).

The schema is created and changed only by the Alembic migrations in ``catenary_migrations``
(``catenary db upgrade``); ``Base.metadata.create_all`` is never used, and a test checks that
these models and the migrations agree.

Conventions:

- lengths of wire geometry in millimetres, positions along the track in metres, as in
  ``FORMATS.md``; every column carries its unit suffix;
- wall-clock times are timezone-aware UTC ``datetime`` (``UTCDateTime``): naive values are
  refused on write, and values read back are always aware, on SQLite as on PostgreSQL;
- enumerations are short strings with a CHECK constraint (the allowed values are the tuples
  below), so that both databases hold plain text and a new value is a migration;
- every constraint and index has a name from ``NAMING_CONVENTION``, so migrations (and SQLite
  batch mode) can refer to it.
"""

from __future__ import annotations

import uuid
from datetime import UTC, datetime
from typing import Any, ClassVar

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    CheckConstraint,
    DateTime,
    Dialect,
    Float,
    ForeignKey,
    ForeignKeyConstraint,
    Index,
    Integer,
    MetaData,
    String,
    Text,
    UniqueConstraint,
    event,
    inspect,
    select,
)
from sqlalchemy.dialects.postgresql import JSONB
from sqlalchemy.engine import Connection
from sqlalchemy.orm import DeclarativeBase, Mapped, Mapper, mapped_column, relationship
from sqlalchemy.types import TypeDecorator

from catenary.domain import ALERT_STATUSES, MAINTENANCE_KINDS
from catenary.domain import CODE_LENGTH as CODE_LENGTH  # the column lengths, for callers here
from catenary.domain import NAME_LENGTH as NAME_LENGTH
from catenary.domain import PATH_LENGTH as PATH_LENGTH

NAMING_CONVENTION: dict[str, str] = {
    "ix": "ix_%(table_name)s_%(column_0_N_name)s",
    "uq": "uq_%(table_name)s_%(column_0_N_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_N_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}

#: Tables that share the database but are not ours (APScheduler's job store): the comparison
#: of models and migrations leaves them alone.
EXTERNAL_TABLES: frozenset[str] = frozenset({"apscheduler_jobs"})

RUN_DIRECTIONS = ("increasing", "decreasing")
RUN_STATUSES = ("processing", "complete", "failed")
ALERT_LEVELS = ("plan", "urgent", "critical")  # catenary.limits.LEVELS
ALERT_KINDS = ("threshold", "forecast", "geometry")
NOTIFICATION_STATUSES = ("pending", "sent", "failed")
USER_ROLES = ("viewer", "planner", "admin")
"""What a user of the web service may do: read; also acknowledge, resolve and record
maintenance; also manage users (README, Users and tokens)."""

SHA256_LENGTH = 64
UUID_LENGTH = 36
RUN_NAMESPACE = uuid.UUID("5a8e3b0c-6f1d-4c2a-9e47-c4a7e2b1d0f3")
"""The namespace of the runs' name-based UUIDs (``run_uuid``): never change it."""


def one_of(column: str, values: tuple[str, ...]) -> str:
    """SQL for a CHECK that ``column`` holds one of ``values``."""
    return f"{column} IN ({', '.join(repr(value) for value in values)})"


def utc_now() -> datetime:
    return datetime.now(UTC)


class UTCDateTime(TypeDecorator[datetime]):
    """A timezone-aware UTC timestamp on every backend.

    Stored as ``TIMESTAMP WITH TIME ZONE`` on PostgreSQL and as UTC text on SQLite (which has
    no time zones). A naive ``datetime`` is refused rather than guessed.
    """

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None or value.utcoffset() is None:
            raise ValueError(f"naive datetime {value.isoformat()}: give a timezone (UTC)")
        return value.astimezone(UTC)

    def process_result_value(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            return value.replace(tzinfo=UTC)
        return value.astimezone(UTC)


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING_CONVENTION)
    type_annotation_map: ClassVar[dict[Any, Any]] = {
        datetime: UTCDateTime(),
        # JSONB on PostgreSQL: comparable (DISTINCT, GROUP BY) and indexable, unlike json
        dict[str, Any]: JSON().with_variant(JSONB(), "postgresql"),
    }


# --- the register ------------------------------------------------------------------------


class Line(Base):
    """A railway line of the register."""

    __tablename__ = "lines"

    id: Mapped[int] = mapped_column(primary_key=True)
    code: Mapped[str] = mapped_column(String(CODE_LENGTH), unique=True)
    name: Mapped[str | None] = mapped_column(String(NAME_LENGTH))

    tracks: Mapped[list[Track]] = relationship(
        back_populates="line", cascade="all, delete-orphan", passive_deletes=True
    )


class Track(Base):
    """A track of a line (its code is unique within the line)."""

    __tablename__ = "tracks"
    __table_args__ = (UniqueConstraint("line_id", "code"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    line_id: Mapped[int] = mapped_column(ForeignKey("lines.id", ondelete="CASCADE"))
    code: Mapped[str] = mapped_column(String(CODE_LENGTH))

    line: Mapped[Line] = relationship(back_populates="tracks")
    masts: Mapped[list[Mast]] = relationship(
        back_populates="track",
        cascade="all, delete-orphan",
        passive_deletes=True,
        order_by="Mast.chainage_m",
    )


class Mast(Base):
    """A mast of the register; a span runs from one mast to the next by chainage and has the
    wire type and the anchor section (``anchor_section``, a code; None: not given) of the mast at
    its start. The design height, line speed (from this mast on) and WGS 84 position are
    optional (None: not given)."""

    __tablename__ = "masts"
    __table_args__ = (
        UniqueConstraint("track_id", "code"),
        Index(None, "track_id", "chainage_m"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    track_id: Mapped[int] = mapped_column(ForeignKey("tracks.id", ondelete="CASCADE"))
    code: Mapped[str] = mapped_column(String(CODE_LENGTH))
    chainage_m: Mapped[float] = mapped_column(Float)
    wire_type: Mapped[str] = mapped_column(String(CODE_LENGTH))
    design_stagger_mm: Mapped[float | None] = mapped_column(Float)
    anchor_section: Mapped[str | None] = mapped_column(String(CODE_LENGTH))
    design_height_mm: Mapped[float | None] = mapped_column(Float)
    line_speed_kmh: Mapped[float | None] = mapped_column(Float)
    latitude: Mapped[float | None] = mapped_column(Float)
    longitude: Mapped[float | None] = mapped_column(Float)

    track: Mapped[Track] = relationship(back_populates="masts")


# --- vehicles and their calibrations --------------------------------------------------------


class Vehicle(Base):
    """An inspection vehicle and its body geometry (FORMATS.md, vehicle geometry)."""

    __tablename__ = "vehicles"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(NAME_LENGTH), unique=True)
    roof_height_mm: Mapped[float] = mapped_column(Float)
    sensor_height_mm: Mapped[float] = mapped_column(Float)
    sensor_baseline_mm: Mapped[float] = mapped_column(Float)

    rig_calibrations: Mapped[list[RigCalibration]] = relationship(
        back_populates="vehicle",
        cascade="all, delete-orphan",
        passive_deletes=True,
        order_by="(RigCalibration.name, RigCalibration.version)",
    )


class RigCalibration(Base):
    """One version of a rig calibration of a vehicle: the TOML file as written by
    ``catenary calibrate``, kept verbatim, and its SHA-256."""

    __tablename__ = "rig_calibrations"
    __table_args__ = (
        UniqueConstraint("vehicle_id", "name", "version"),
        CheckConstraint("version >= 1", name="version_positive"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    vehicle_id: Mapped[int] = mapped_column(ForeignKey("vehicles.id", ondelete="CASCADE"))
    name: Mapped[str] = mapped_column(String(NAME_LENGTH))
    version: Mapped[int] = mapped_column(Integer)
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    content_toml: Mapped[str] = mapped_column(Text)
    sha256: Mapped[str] = mapped_column(String(SHA256_LENGTH))

    vehicle: Mapped[Vehicle] = relationship(back_populates="rig_calibrations")


# --- runs and what they measured ------------------------------------------------------------


class Run(Base):
    """One inspection run: one recorded run file measured with one rig calibration.

    A run's identity is its content, the same on every machine: the run file's SHA-256
    (``source_sha256``) and the rig calibration's content SHA-256 (``rig_sha256``), unique
    together; ``uuid`` is derived from them (``run_uuid``), so a run processed on two vehicles,
    or pushed twice, is one run. What it measured belongs to its processings; ``processing_id``
    is its latest, the only one alerts, forecasts, reports and exports see
    (``span_measurements``).
    """

    __tablename__ = "runs"
    __table_args__ = (
        UniqueConstraint("source_sha256", "rig_sha256"),
        # the target of span_measurements' (run_id, track_id) foreign key
        UniqueConstraint("id", "track_id"),
        Index(None, "line_id", "track_id", "started_at"),
        Index(None, "track_id", "started_at"),  # the alert evaluation, a track at a time
        CheckConstraint(one_of("direction", RUN_DIRECTIONS), name="direction"),
        CheckConstraint(one_of("status", RUN_STATUSES), name="status"),
        CheckConstraint("scans >= 0", name="scans_not_negative"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    uuid: Mapped[str] = mapped_column(String(UUID_LENGTH), unique=True)
    line_id: Mapped[int] = mapped_column(ForeignKey("lines.id", ondelete="RESTRICT"))
    track_id: Mapped[int | None] = mapped_column(ForeignKey("tracks.id", ondelete="RESTRICT"))
    direction: Mapped[str] = mapped_column(String(16))
    vehicle_id: Mapped[int] = mapped_column(ForeignKey("vehicles.id", ondelete="RESTRICT"))
    rig_calibration_id: Mapped[int] = mapped_column(
        ForeignKey("rig_calibrations.id", ondelete="RESTRICT")
    )
    source_file: Mapped[str] = mapped_column(String(PATH_LENGTH))
    source_sha256: Mapped[str] = mapped_column(String(SHA256_LENGTH))
    # the run file in the store (``runs/RUN.h5``), once it was sent there (push --run-files)
    source_key: Mapped[str | None] = mapped_column(String(PATH_LENGTH))
    rig_sha256: Mapped[str] = mapped_column(String(SHA256_LENGTH))
    started_at: Mapped[datetime]
    scans: Mapped[int] = mapped_column(Integer, default=0)
    status: Mapped[str] = mapped_column(String(16), default="processing")
    error: Mapped[str | None] = mapped_column(Text)
    # the latest processing (None only while the first is being stored)
    processing_id: Mapped[int | None] = mapped_column(
        ForeignKey("processings.id", ondelete="SET NULL", use_alter=True)
    )
    # when the run's track was last evaluated for alerts with this run's latest processing in
    # it; None: pending (runs stored before this column count as pending)
    alerts_evaluated_at: Mapped[datetime | None] = mapped_column(index=True)

    line: Mapped[Line] = relationship()
    track: Mapped[Track | None] = relationship()
    vehicle: Mapped[Vehicle] = relationship()
    rig_calibration: Mapped[RigCalibration] = relationship()
    processing: Mapped[Processing | None] = relationship(
        foreign_keys=[processing_id], post_update=True
    )
    processings: Mapped[list[Processing]] = relationship(
        back_populates="run",
        foreign_keys="Processing.run_id",
        cascade="all, delete-orphan",
        passive_deletes=True,
        order_by="Processing.processed_at",
    )
    span_measurements: Mapped[list[SpanMeasurement]] = relationship(
        primaryjoin="and_(Run.processing_id == foreign(SpanMeasurement.processing_id), "
        "Run.id == SpanMeasurement.run_id)",
        viewonly=True,
        order_by="(SpanMeasurement.span, SpanMeasurement.wire)",
    )


def run_uuid(source_sha256: str, rig_sha256: str) -> str:
    """The UUID of the run of this run file content with this rig calibration content: the
    same on every machine (a name-based UUID, version 5)."""
    return str(uuid.uuid5(RUN_NAMESPACE, f"{source_sha256}:{rig_sha256}"))


class Processing(Base):
    """One processing of a run: a processor of a package version with settings (``settings``,
    hashed in ``settings_sha256``) and the run's rig calibration, what it found (the chainage
    alignment, the length) and what it stored: span measurements and the samples file in the
    store (``samples_key``, a portable key; its size and SHA-256 checked when it moves).

    ``uuid`` is random: a run processed again is a new processing, wherever that happens.
    Processings that migrated from before they were recorded have ``settings`` None.
    """

    __tablename__ = "processings"
    __table_args__ = (
        Index(None, "run_id", "processed_at"),
        CheckConstraint("samples_size_bytes >= 0", name="samples_size_not_negative"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    uuid: Mapped[str] = mapped_column(String(UUID_LENGTH), unique=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"))
    processor: Mapped[str] = mapped_column(String(NAME_LENGTH))
    package_version: Mapped[str] = mapped_column(String(CODE_LENGTH))
    settings_sha256: Mapped[str] = mapped_column(String(SHA256_LENGTH))
    settings: Mapped[dict[str, Any] | None]
    rig_calibration_id: Mapped[int] = mapped_column(
        ForeignKey("rig_calibrations.id", ondelete="RESTRICT")
    )
    processed_at: Mapped[datetime]
    # the wire type given for the whole run; None when it comes from the mast register per span
    wire_type: Mapped[str | None] = mapped_column(String(CODE_LENGTH))
    length_m: Mapped[float] = mapped_column(Float, default=0.0)
    # how chainage was found: chainage = offset + sign * scale * encoder position; aligned to
    # the register's masts through ``alignment_matched`` registration points (False: start +
    # position); None for runs stored before these columns
    chainage_aligned: Mapped[bool | None]
    chainage_offset_m: Mapped[float | None] = mapped_column(Float)
    encoder_scale: Mapped[float | None] = mapped_column(Float)
    alignment_matched: Mapped[int | None] = mapped_column(Integer)
    alignment_rms_m: Mapped[float | None] = mapped_column(Float)
    samples_key: Mapped[str | None] = mapped_column(String(PATH_LENGTH))
    samples_size_bytes: Mapped[int | None] = mapped_column(BigInteger)
    samples_sha256: Mapped[str | None] = mapped_column(String(SHA256_LENGTH))

    run: Mapped[Run] = relationship(back_populates="processings", foreign_keys=[run_id])
    rig_calibration: Mapped[RigCalibration] = relationship()
    span_measurements: Mapped[list[SpanMeasurement]] = relationship(
        back_populates="processing",
        cascade="all, delete-orphan",
        passive_deletes=True,
        order_by="(SpanMeasurement.span, SpanMeasurement.wire)",
    )


class SpanMeasurement(Base):
    """One span and contact wire of one processing of a run: the ``spans`` export row
    (FORMATS.md).

    ``track_id`` is the run's track, kept here so that measurements are found by track and
    chainage across runs; a foreign key on ``(run_id, track_id)`` keeps it equal to the run's.
    The ORM fills it from the run on insert; a bulk ``insert()`` must give it.
    """

    __tablename__ = "span_measurements"
    __table_args__ = (
        # its index, led by processing_id, also serves look-ups by processing
        UniqueConstraint("processing_id", "span", "wire"),
        Index(None, "run_id"),
        ForeignKeyConstraint(
            ["run_id", "track_id"],
            ["runs.id", "runs.track_id"],
            ondelete="CASCADE",
            onupdate="CASCADE",
        ),
        Index(None, "track_id", "start_chainage_m"),
        Index(None, "track_id", "mast_from"),  # a span's history (``span_trends``)
        # the thinnest spans of a processing (the overview's worst spans)
        Index(None, "processing_id", "min_residual_thickness_mm"),
        CheckConstraint("wire >= 0", name="wire_not_negative"),
        CheckConstraint("wire_position >= 0", name="wire_position_not_negative"),
        CheckConstraint("samples >= 0", name="samples_not_negative"),
        CheckConstraint("end_chainage_m >= start_chainage_m", name="chainage_order"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"))
    processing_id: Mapped[int] = mapped_column(ForeignKey("processings.id", ondelete="CASCADE"))
    track_id: Mapped[int | None] = mapped_column(Integer)
    span: Mapped[int] = mapped_column(Integer)
    # mast codes; None when the span was found without a mast register
    mast_from: Mapped[str | None] = mapped_column(String(CODE_LENGTH))
    mast_to: Mapped[str | None] = mapped_column(String(CODE_LENGTH))
    start_chainage_m: Mapped[float] = mapped_column(Float)
    end_chainage_m: Mapped[float] = mapped_column(Float)
    wire: Mapped[int] = mapped_column(Integer)
    # the wire's rank in the span, left to right looking toward increasing chainage: the
    # identity users see (catenary.positions)
    wire_position: Mapped[int] = mapped_column(Integer)
    wire_type: Mapped[str] = mapped_column(String(CODE_LENGTH))
    min_residual_thickness_mm: Mapped[float] = mapped_column(Float)
    min_at_chainage_m: Mapped[float] = mapped_column(Float)
    mean_residual_thickness_mm: Mapped[float] = mapped_column(Float)
    height_min_mm: Mapped[float] = mapped_column(Float)
    height_max_mm: Mapped[float] = mapped_column(Float)
    stagger_min_mm: Mapped[float] = mapped_column(Float)
    stagger_max_mm: Mapped[float] = mapped_column(Float)
    samples: Mapped[int] = mapped_column(Integer)
    # medians within MAST_WINDOW_M of the span's masts [mm]; None: no sample there
    height_at_start_mm: Mapped[float | None] = mapped_column(Float)
    height_at_end_mm: Mapped[float | None] = mapped_column(Float)
    stagger_at_start_mm: Mapped[float | None] = mapped_column(Float)

    run: Mapped[Run] = relationship(foreign_keys=[run_id])
    processing: Mapped[Processing] = relationship(back_populates="span_measurements")


@event.listens_for(SpanMeasurement, "before_insert")
def _run_of_processing(
    mapper: Mapper[Any], connection: Connection, target: SpanMeasurement
) -> None:
    """Copy the processing's run, and the run's track, onto a new span measurement that does
    not give them."""
    state = inspect(target).dict  # loaded or assigned, never lazy-loaded in a flush
    processing = state.get("processing")
    if target.run_id is None:
        if isinstance(processing, Processing):
            target.run_id = processing.run_id
        else:
            target.run_id = connection.scalar(
                select(Processing.run_id).where(Processing.id == target.processing_id)
            )
    if target.track_id is not None:
        return
    run = state.get("run")
    if not isinstance(run, Run) and isinstance(processing, Processing):
        run = inspect(processing).dict.get("run")
    if isinstance(run, Run) and run.id == target.run_id:
        target.track_id = run.track_id
    else:
        target.track_id = connection.scalar(select(Run.track_id).where(Run.id == target.run_id))


# --- maintenance ----------------------------------------------------------------------------


class MaintenanceAction(Base):
    """Work done on the wire of a track between two chainages (all wires when ``wire`` is
    None)."""

    __tablename__ = "maintenance_actions"
    __table_args__ = (
        Index(None, "track_id", "from_chainage_m"),
        CheckConstraint(one_of("kind", MAINTENANCE_KINDS), name="kind"),
        CheckConstraint("to_chainage_m >= from_chainage_m", name="chainage_order"),
        CheckConstraint("wire >= 0", name="wire_not_negative"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    track_id: Mapped[int] = mapped_column(ForeignKey("tracks.id", ondelete="RESTRICT"))
    kind: Mapped[str] = mapped_column(String(32))
    from_chainage_m: Mapped[float] = mapped_column(Float)
    to_chainage_m: Mapped[float] = mapped_column(Float)
    mast_from: Mapped[str | None] = mapped_column(String(CODE_LENGTH))
    mast_to: Mapped[str | None] = mapped_column(String(CODE_LENGTH))
    wire: Mapped[int | None] = mapped_column(Integer)
    performed_at: Mapped[datetime]
    recorded_by: Mapped[str] = mapped_column(String(NAME_LENGTH))
    note: Mapped[str | None] = mapped_column(Text)

    track: Mapped[Track] = relationship()


class Alert(Base):
    """A maintenance alert on a stretch of wire: a threshold crossed, or forecast to be.

    ``condition_key`` identifies the condition (rule, track, wire, stretch, and whatever makes a
    recurrence after repair a new condition): it is unique, so the same condition is never
    raised twice. ``details`` holds what the rule wants to keep (e.g. a forecast's wear rate and
    date).
    """

    __tablename__ = "alerts"
    __table_args__ = (
        Index(None, "status"),
        Index(None, "track_id", "start_chainage_m"),
        # the foreign keys that a deleted run or span measurement sets to NULL
        Index(None, "span_measurement_id"),
        Index(None, "resolved_by_run_id"),
        CheckConstraint(one_of("level", ALERT_LEVELS), name="level"),
        CheckConstraint(one_of("kind", ALERT_KINDS), name="kind"),
        CheckConstraint(one_of("status", ALERT_STATUSES), name="status"),
        CheckConstraint("end_chainage_m >= start_chainage_m", name="chainage_order"),
        CheckConstraint("wire >= 0", name="wire_not_negative"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    track_id: Mapped[int] = mapped_column(ForeignKey("tracks.id", ondelete="RESTRICT"))
    wire: Mapped[int] = mapped_column(Integer)
    mast_from: Mapped[str | None] = mapped_column(String(CODE_LENGTH))
    mast_to: Mapped[str | None] = mapped_column(String(CODE_LENGTH))
    start_chainage_m: Mapped[float] = mapped_column(Float)
    end_chainage_m: Mapped[float] = mapped_column(Float)
    span_measurement_id: Mapped[int | None] = mapped_column(
        ForeignKey("span_measurements.id", ondelete="SET NULL")
    )
    rule: Mapped[str] = mapped_column(String(NAME_LENGTH))
    level: Mapped[str] = mapped_column(String(16))
    kind: Mapped[str] = mapped_column(String(16))
    value: Mapped[float] = mapped_column(Float)
    threshold: Mapped[float] = mapped_column(Float)
    status: Mapped[str] = mapped_column(String(16), default="open")
    raised_at: Mapped[datetime] = mapped_column(default=utc_now)
    acknowledged_by: Mapped[str | None] = mapped_column(String(NAME_LENGTH))
    acknowledged_at: Mapped[datetime | None]
    resolved_at: Mapped[datetime | None]
    resolved_by_run_id: Mapped[int | None] = mapped_column(
        ForeignKey("runs.id", ondelete="SET NULL")
    )
    resolved_by_action_id: Mapped[int | None] = mapped_column(
        ForeignKey("maintenance_actions.id", ondelete="SET NULL")
    )
    condition_key: Mapped[str] = mapped_column(String(255), unique=True)
    details: Mapped[dict[str, Any] | None]

    track: Mapped[Track] = relationship()
    span_measurement: Mapped[SpanMeasurement | None] = relationship()
    resolved_by_run: Mapped[Run | None] = relationship()
    resolved_by_action: Mapped[MaintenanceAction | None] = relationship()
    notifications: Mapped[list[AlertNotification]] = relationship(
        back_populates="alert", cascade="all, delete-orphan", passive_deletes=True
    )


class AlertNotification(Base):
    """The delivery of one alert to one notification channel, retried until sent.

    ``notifier`` holds the channel's name (``catenary.maintenance.notifications``);
    ``next_attempt_at`` is when it is next due (None: at once, while attempts remain; a failed one
    with None has used them all).
    """

    __tablename__ = "alert_notifications"
    __table_args__ = (
        UniqueConstraint("alert_id", "notifier"),
        Index(None, "status"),
        CheckConstraint(one_of("status", NOTIFICATION_STATUSES), name="status"),
        CheckConstraint("attempts >= 0", name="attempts_not_negative"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    alert_id: Mapped[int] = mapped_column(ForeignKey("alerts.id", ondelete="CASCADE"))
    notifier: Mapped[str] = mapped_column(String(NAME_LENGTH))
    status: Mapped[str] = mapped_column(String(16), default="pending")
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    last_error: Mapped[str | None] = mapped_column(Text)
    next_attempt_at: Mapped[datetime | None]
    updated_at: Mapped[datetime] = mapped_column(default=utc_now, onupdate=utc_now)

    alert: Mapped[Alert] = relationship(back_populates="notifications")


# --- services -------------------------------------------------------------------------------


class SchedulerLease(Base):
    """The lease that the running ``catenary scheduler`` of a database holds, renewed by its
    heartbeat: a second scheduler waits as a standby until ``expires_at`` has passed.

    ``holder`` names the holder for people (``host:pid``); ``name`` is the lease's name (one
    row per service that must run once per database).
    """

    __tablename__ = "scheduler_leases"

    name: Mapped[str] = mapped_column(String(64), primary_key=True)
    holder: Mapped[str] = mapped_column(String(NAME_LENGTH))
    host: Mapped[str] = mapped_column(String(NAME_LENGTH))
    pid: Mapped[int] = mapped_column(Integer)
    acquired_at: Mapped[datetime]
    heartbeat_at: Mapped[datetime]
    expires_at: Mapped[datetime]


# --- users ----------------------------------------------------------------------------------


SIGN_IN_KEY_LENGTH = 200
"""The longest sign-in limit key (``user:`` and a name, ``address:`` and an IP address)."""


class User(Base):
    """A person who signs in to the web service (``catenary.storage.users``).

    ``name`` is an identifier (printable, at most ``NAME_LENGTH`` characters); ``role`` one of
    ``USER_ROLES``; ``password_hash`` an Argon2 hash in its PHC string form, never the password.
    A disabled user keeps their rows (tokens, audit entries) but is refused.
    """

    __tablename__ = "users"
    __table_args__ = (CheckConstraint(one_of("role", USER_ROLES), name="role"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(NAME_LENGTH), unique=True)
    role: Mapped[str] = mapped_column(String(16))
    password_hash: Mapped[str] = mapped_column(String(255))
    disabled: Mapped[bool] = mapped_column(Boolean, default=False)
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    updated_at: Mapped[datetime] = mapped_column(default=utc_now, onupdate=utc_now)

    tokens: Mapped[list[ApiToken]] = relationship(
        back_populates="user", cascade="all, delete-orphan", passive_deletes=True
    )


class ApiToken(Base):
    """An API token of a user (``Authorization: Bearer``): only the SHA-256 of the token is
    kept (hex), so the token itself is shown once, when it is created. A token is refused once
    ``revoked_at`` is set or ``expires_at`` has passed."""

    __tablename__ = "api_tokens"
    __table_args__ = (UniqueConstraint("user_id", "name"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"))
    name: Mapped[str] = mapped_column(String(NAME_LENGTH))
    token_hash: Mapped[str] = mapped_column(String(SHA256_LENGTH), unique=True)
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    last_used_at: Mapped[datetime | None]
    expires_at: Mapped[datetime | None]
    revoked_at: Mapped[datetime | None]

    user: Mapped[User] = relationship(back_populates="tokens")


class SignInFailure(Base):
    """A failed sign-in to the web service, counted against ``key`` (``user:NAME`` or
    ``address:IP``) for the sign-in limit of every process of the service
    (``catenary.web.auth.SignInLimiter``); rows older than the limit's window are deleted."""

    __tablename__ = "sign_in_failures"
    __table_args__ = (Index(None, "key", "at"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    key: Mapped[str] = mapped_column(String(SIGN_IN_KEY_LENGTH))
    at: Mapped[datetime] = mapped_column()


class AuditEntry(Base):
    """One change, who made it and when: ``actor`` is a user's name, or the system user
    (``system:<os user>@<host>``) for a change made on the command line; ``action`` says what
    was done (``alert.acknowledge``, ``user.add``...), ``target`` to what (``alert 12``) and
    ``details`` the rest (the ``--by`` name, what changed)."""

    __tablename__ = "audit_entries"
    __table_args__ = (Index(None, "at"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    at: Mapped[datetime] = mapped_column(default=utc_now)
    actor: Mapped[str] = mapped_column(String(NAME_LENGTH))
    action: Mapped[str] = mapped_column(String(64))
    target: Mapped[str] = mapped_column(String(NAME_LENGTH))
    details: Mapped[dict[str, Any]] = mapped_column(default=dict)
