"""The fleet's data for analysts: runs, span measurements, span-wire histories, alerts and
samples as pandas DataFrames.

Open it from a config as the commands do (``catenary.config.load_settings``: ``--config``,
``$CATENARY_CONFIG``, ... and ``database_url`` for ``--db``)::

    with FleetData.open("fleet.toml") as fleet:
        spans = fleet.spans("L100", "1", since=datetime(2024, 1, 1, tzinfo=UTC))
        wear = fleet.samples("L100", "1", 1000.0, 1050.0)

Only what the platform itself sees is returned: a run's latest processing (``Run.processing_id``).
Units are in the column names (metres along the track, millimetres of wire geometry); times are
timezone-aware UTC. Every frame has its columns and dtypes even when empty. A line or track code
that is not in the database is a one-line ``UserError`` naming it (a misspelt code never reads
as "no data"); a known line or track without data gives an empty frame.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from contextlib import ExitStack, contextmanager
from datetime import UTC, datetime
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.dataset as ds
from sqlalchemy import Select, and_, select
from sqlalchemy.engine import Connection, Engine
from sqlalchemy.orm import aliased

from catenary.config import Settings, load_settings
from catenary.domain import ALERT_STATUSES
from catenary.errors import UserError
from catenary.maintenance.alerts.trackdata import TrackData
from catenary.maintenance.history import span_histories
from catenary.measurement.samples import ADDED_COLUMNS, SAMPLES_SCHEMA, stored_samples_key
from catenary.measurement.spans import SPAN_COLUMNS
from catenary.storage.database import connected, open_database, session_scope
from catenary.storage.models import Alert, Line, Processing, Run, SpanMeasurement, Track, Vehicle
from catenary.storage.store import Store, StoreError, open_store

__all__ = [
    "ALERT_COLUMNS",
    "HISTORY_COLUMNS",
    "RUN_COLUMNS",
    "SAMPLE_COLUMNS",
    "SPAN_FRAME_COLUMNS",
    "FleetData",
]

UTC_TIME = "datetime64[us, UTC]"

RUN_COLUMNS: dict[str, str] = {
    "uuid": "string",
    "id": "int64",
    "line": "string",
    "track": "string",
    "direction": "string",
    "vehicle": "string",
    "started_at": UTC_TIME,
    "scans": "int64",
    "status": "string",
    "processing": "string",
    "processor": "string",
    "package_version": "string",
    "processed_at": UTC_TIME,
    "length_m": "float64",
    "samples_key": "string",
}
"""``FleetData.runs``' columns and dtypes: the run (``uuid``, ``id`` in this database), where
and how it ran, its status (``processing``, ``complete``, ``failed``) and its latest processing
(``processing``: its UUID; ``length_m``: the length measured [m]; ``samples_key``: its samples
file in the store)."""

SPAN_FRAME_COLUMNS: dict[str, str] = {
    "run": "string",
    "track": "string",
    "started_at": UTC_TIME,
    "direction": "string",
    "vehicle": "string",
    **{
        c: "string"
        if c in ("mast_from", "mast_to", "wire_type")
        else "int64"
        if c in ("span", "wire", "samples")
        else "float64"
        for c in SPAN_COLUMNS
    },
}
"""``FleetData.spans``' columns: the run's UUID, track, start, direction and vehicle, then the
``spans`` export's columns (FORMATS.md: chainages [m], residual thickness, height and stagger
[mm] in the run's track frame, ``samples`` counted)."""

HISTORY_COLUMNS: dict[str, str] = {
    "mast_from": "string",
    "mast_to": "string",
    "start_chainage_m": "float64",
    "end_chainage_m": "float64",
    "position": "int64",
    "run": "string",
    "started_at": UTC_TIME,
    "wire": "int64",
    "wire_type": "string",
    "min_residual_thickness_mm": "float64",
    "mean_residual_thickness_mm": "float64",
    "samples": "int64",
    "since_repair": "bool",
}
"""``FleetData.span_histories``' columns: the stretch (its masts, None when measured without a
register, and the row's chainages [m]), the wire's ``position`` in it
(``catenary.maintenance.history``), the run, its wire number and the span's wire type, the
residual thickness [mm] and the samples counted, and
whether the row is after the last repair of its wire (``since_repair``; False: a wire since
replaced or repaired)."""

ALERT_COLUMNS: dict[str, str] = {
    "id": "int64",
    "line": "string",
    "track": "string",
    "wire": "int64",
    "mast_from": "string",
    "mast_to": "string",
    "start_chainage_m": "float64",
    "end_chainage_m": "float64",
    "rule": "string",
    "level": "string",
    "kind": "string",
    "value": "float64",
    "threshold": "float64",
    "status": "string",
    "raised_at": UTC_TIME,
    "acknowledged_by": "string",
    "acknowledged_at": UTC_TIME,
    "resolved_at": UTC_TIME,
    "resolved_by_run": "string",
    "resolved_by_action_id": "Int64",
    "span_measurement_id": "Int64",
    "condition_key": "string",
    "details": "object",
}
"""``FleetData.alerts``' columns: the ``Alert`` columns (``value`` and ``threshold`` are residual
thicknesses [mm]; ``resolved_by_run`` the resolving run's UUID; ``details`` a dict or None)
with the line and track codes."""

SAMPLE_COLUMNS = tuple(SAMPLES_SCHEMA.names)
"""The samples files' columns (``catenary.measurement.samples``), those ``FleetData.samples``
may select."""


def _frame(rows: Sequence[Any], dtypes: Mapping[str, str]) -> pd.DataFrame:
    """Rows (tuples in the order of ``dtypes``) as a frame of those dtypes, empty or not."""
    frame = pd.DataFrame.from_records(list(rows), columns=list(dtypes))
    return frame.astype(dict(dtypes))


def _one_line(exc: BaseException) -> str:
    """An exception's message on one line."""
    return " ".join(str(exc).split()) or type(exc).__name__


def _utc(name: str, value: datetime | None) -> datetime | None:
    """``value`` in UTC; a naive ``datetime`` is a ``UserError`` (its zone would be a guess)."""
    if value is None:
        return None
    if value.tzinfo is None or value.utcoffset() is None:
        raise UserError(f"{name} {value.isoformat()}: give a timezone-aware datetime (UTC)")
    return value.astimezone(UTC)


class FleetData:
    """A fleet's database and store, read as DataFrames (``FleetData.open``; a context manager
    that closes the database's connections)."""

    def __init__(self, settings: Settings, engine: Engine, closing: ExitStack) -> None:
        self.settings = settings
        self.engine = engine
        self._closing = closing
        self._store: Store | None = None

    @classmethod
    def open(
        cls, config: str | Path | None = None, *, database_url: str | None = None
    ) -> FleetData:
        """The fleet of the config file ``config`` (default: as the commands find it) or of
        ``database_url``; its database must be migrated. The config's statement timeout of
        interactive commands applies (``[database] statement_timeout_s``). The store is opened
        when samples are first read."""
        settings = load_settings(
            config_path=None if config is None else Path(config), database_url=database_url
        )
        closing = ExitStack()
        engine = closing.enter_context(open_database(settings))
        return cls(settings, engine, closing)

    def close(self) -> None:
        """Close the database's connections."""
        self._closing.close()

    def __enter__(self) -> FleetData:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    @property
    def store(self) -> Store:
        """The store of the samples files (``[store]``), opened on first use."""
        if self._store is None:
            self._store = open_store(self.settings)
        return self._store

    @contextmanager
    def _reading(self) -> Iterator[Connection]:
        with connected(self.engine, read_only=True) as connection, connection.begin():
            yield connection

    # --- where ------------------------------------------------------------------------------

    @staticmethod
    def _line_id(connection: Connection, line: str) -> int:
        found = connection.scalar(select(Line.id).where(Line.code == line))
        if found is None:
            known = connection.scalars(select(Line.code).order_by(Line.code)).all()
            raise UserError(f"line {line!r} is not in the database (lines: {', '.join(known)})")
        return int(found)

    @staticmethod
    def _track_id(connection: Connection, line: str, track: str) -> int:
        line_id = FleetData._line_id(connection, line)
        found = connection.scalar(
            select(Track.id).where(Track.line_id == line_id, Track.code == track)
        )
        if found is None:
            known = connection.scalars(
                select(Track.code).where(Track.line_id == line_id).order_by(Track.code)
            ).all()
            raise UserError(
                f"line {line!r} has no track {track!r} (tracks: {', '.join(known) or 'none'})"
            )
        return int(found)

    def _where(
        self,
        connection: Connection,
        query: Select[*tuple[Any, ...]],
        line: str | None,
        track: str | None,
    ) -> Select[*tuple[Any, ...]]:
        """``query`` (over ``Run``) limited to the runs of ``line`` and ``track``."""
        if track is not None:
            if line is None:
                raise UserError(f"track {track!r}: give its line too")
            return query.where(Run.track_id == self._track_id(connection, line, track))
        if line is not None:
            return query.where(Run.line_id == self._line_id(connection, line))
        return query

    # --- the database -----------------------------------------------------------------------

    def runs(self, line: str | None = None, track: str | None = None) -> pd.DataFrame:
        """One row per run (of ``line``, of its ``track``; default all), by start time:
        ``RUN_COLUMNS``."""
        query = (
            select(
                Run.uuid,
                Run.id,
                Line.code,
                Track.code,
                Run.direction,
                Vehicle.name,
                Run.started_at,
                Run.scans,
                Run.status,
                Processing.uuid,
                Processing.processor,
                Processing.package_version,
                Processing.processed_at,
                Processing.length_m,
                Processing.samples_key,
            )
            .join(Line, Line.id == Run.line_id)
            .outerjoin(Track, Track.id == Run.track_id)
            .join(Vehicle, Vehicle.id == Run.vehicle_id)
            .outerjoin(Processing, Processing.id == Run.processing_id)
            .order_by(Run.started_at, Run.id)
        )
        with self._reading() as connection:
            rows = connection.execute(self._where(connection, query, line, track)).all()
        return _frame(rows, RUN_COLUMNS)

    def spans(
        self,
        line: str,
        track: str | None = None,
        *,
        since: datetime | None = None,
        until: datetime | None = None,
    ) -> pd.DataFrame:
        """The span measurements of the complete runs of ``line`` (of its ``track``) that
        started at ``since`` or later and before ``until`` (aware datetimes), their latest
        processings only, by start time, span and wire: ``SPAN_FRAME_COLUMNS``."""
        start, end = _utc("since", since), _utc("until", until)
        sm = SpanMeasurement
        query = (
            select(
                Run.uuid,
                Track.code,
                Run.started_at,
                Run.direction,
                Vehicle.name,
                *(getattr(sm, c) for c in SPAN_COLUMNS),
            )
            .join(sm, and_(sm.run_id == Run.id, sm.processing_id == Run.processing_id))
            .outerjoin(Track, Track.id == Run.track_id)
            .join(Vehicle, Vehicle.id == Run.vehicle_id)
            .where(Run.status == "complete")
            .order_by(Run.started_at, Run.id, sm.span, sm.wire)
        )
        if start is not None:
            query = query.where(Run.started_at >= start)
        if end is not None:
            query = query.where(Run.started_at < end)
        with self._reading() as connection:
            rows = connection.execute(self._where(connection, query, line, track)).all()
        return _frame(rows, SPAN_FRAME_COLUMNS)

    def span_histories(self, line: str, track: str) -> pd.DataFrame:
        """The span-wire histories of a track: one row per stretch, wire position and complete
        run, as the alerts see them (``catenary.maintenance.history``), ordered by stretch
        (masts by chainage, then stretches measured without a register by chainage), position
        and time: ``HISTORY_COLUMNS``. Plot ``min_residual_thickness_mm`` against
        ``started_at`` per (``mast_from``, ``mast_to``, ``position``) for wear over time."""
        with session_scope(self.engine, read_only=True) as session:
            track_id = self._track_id(session.connection(), line, track)
            wire_types = session.scalars(
                select(SpanMeasurement.wire_type)
                .where(SpanMeasurement.track_id == track_id)
                .distinct()
                .order_by(SpanMeasurement.wire_type)
            ).all()
            data = TrackData(session, track_id, wire_types or ["-"])  # none: a CASE of no WHEN
            uuids = dict(
                session.execute(select(Run.id, Run.uuid).where(Run.track_id == track_id)).all()
            )
        rows = data.rows
        hist = span_histories(rows, data.repairs)
        run = np.searchsorted(data.run_id, rows.run_id)
        by_masts = rows.mast_from >= 0
        low = np.where(by_masts, rows.mast_from, rows.start_m)
        high = np.where(by_masts, rows.mast_to, rows.end_m)
        order = np.lexsort((rows.time_years, hist.row_position, high, low, ~by_masts))
        codes = np.array([*data.mast_code, None], dtype=object)  # index -1: None
        frame = pd.DataFrame(
            {
                "mast_from": codes[rows.mast_from[order]],
                "mast_to": codes[rows.mast_to[order]],
                "start_chainage_m": rows.start_m[order],
                "end_chainage_m": rows.end_m[order],
                "position": hist.row_position[order],
                "run": [uuids[int(r)] for r in rows.run_id[order]],
                "started_at": pd.Series(
                    [data.run_started[int(r)] for r in run[order]], dtype=UTC_TIME
                ),
                "wire": rows.wire[order],
                "wire_type": [wire_types[int(w)] for w in rows.wire_type[order]],
                "min_residual_thickness_mm": rows.min_thickness_mm[order],
                "mean_residual_thickness_mm": rows.mean_thickness_mm[order],
                "samples": rows.samples[order],
                "since_repair": hist.row_history[order] >= 0,
            },
            columns=list(HISTORY_COLUMNS),
        )
        return frame.astype(HISTORY_COLUMNS)

    def alerts(
        self, status: str | None = None, line: str | None = None, track: str | None = None
    ) -> pd.DataFrame:
        """The alerts (with ``status``, one of ``open``, ``acknowledged``, ``resolved``; of
        ``line``, of its ``track``), by time raised: ``ALERT_COLUMNS``."""
        if status is not None and status not in ALERT_STATUSES:
            raise UserError(f"alert status {status!r}: one of {', '.join(ALERT_STATUSES)}")
        resolver = aliased(Run)
        query = (
            select(
                Alert.id,
                Line.code,
                Track.code,
                Alert.wire,
                Alert.mast_from,
                Alert.mast_to,
                Alert.start_chainage_m,
                Alert.end_chainage_m,
                Alert.rule,
                Alert.level,
                Alert.kind,
                Alert.value,
                Alert.threshold,
                Alert.status,
                Alert.raised_at,
                Alert.acknowledged_by,
                Alert.acknowledged_at,
                Alert.resolved_at,
                resolver.uuid,
                Alert.resolved_by_action_id,
                Alert.span_measurement_id,
                Alert.condition_key,
                Alert.details,
            )
            .join(Track, Track.id == Alert.track_id)
            .join(Line, Line.id == Track.line_id)
            .outerjoin(resolver, resolver.id == Alert.resolved_by_run_id)
            .order_by(Alert.raised_at, Alert.id)
        )
        if status is not None:
            query = query.where(Alert.status == status)
        with self._reading() as connection:
            if track is not None:
                if line is None:
                    raise UserError(f"track {track!r}: give its line too")
                query = query.where(Alert.track_id == self._track_id(connection, line, track))
            elif line is not None:
                query = query.where(Track.line_id == self._line_id(connection, line))
            rows = connection.execute(query).all()
        return _frame(rows, ALERT_COLUMNS)

    # --- the store --------------------------------------------------------------------------

    def _sample_files(
        self, line: str, track: str, runs: Sequence[str] | None
    ) -> list[tuple[str, str]]:
        """(run UUID, samples key) of the latest processings of the complete runs of the
        track (or of ``runs``, UUIDs), by start time."""
        query = (
            select(Run.uuid, Processing.samples_key)
            .join(Processing, Processing.id == Run.processing_id)
            .where(Run.status == "complete", Processing.samples_key.is_not(None))
            .order_by(Run.started_at, Run.id)
        )
        if runs is not None:
            query = query.where(Run.uuid.in_(list(runs)))
        with self._reading() as connection:
            files = [
                (str(u), str(k))
                for u, k in connection.execute(self._where(connection, query, line, track))
            ]
        if runs is not None:
            missing = sorted(set(runs) - {u for u, _ in files})
            if missing:
                raise UserError(
                    f"run {missing[0]} is not a complete run of line {line!r} track {track!r} "
                    "with a samples file"
                )
        for run, key in files:
            stored_samples_key(run, key)
        return files

    def samples_dataset(
        self, line: str, track: str, *, runs: Sequence[str] | None = None
    ) -> ds.Dataset:
        """The samples files of the latest processings of the track's complete runs (or of
        ``runs``, UUIDs) as one Parquet dataset in the store, with a ``run`` column (the run's
        UUID, from the database: also for files stored before keys named their run). Scan it
        with a filter (``pyarrow.dataset.field("chainage_m") < 1200``): row groups outside it
        are skipped by their statistics, never read. A column an older file lacks
        (``ADDED_COLUMNS``) reads as null."""
        return self._dataset(self._sample_files(line, track, runs))

    def _dataset(self, files: Sequence[tuple[str, str]]) -> ds.Dataset:
        """``samples_dataset`` of these (run UUID, samples key)."""
        schema = pa.schema([*SAMPLES_SCHEMA, pa.field("run", pa.string())])
        try:
            return ds.FileSystemDataset.from_paths(
                [key for _, key in files],
                schema=schema,
                format=ds.ParquetFileFormat(),
                filesystem=self.store.filesystem,
                partitions=[ds.field("run") == run for run, _ in files],
            )
        except (OSError, pa.ArrowInvalid) as exc:
            raise StoreError(
                f"{self.store.url}: cannot open the samples: {_one_line(exc)}"
            ) from None

    def samples(
        self,
        line: str,
        track: str,
        start_chainage_m: float,
        end_chainage_m: float,
        *,
        runs: Sequence[str] | None = None,
        columns: Sequence[str] | None = None,
    ) -> pd.DataFrame:
        """The samples at chainages ``start_chainage_m <= chainage_m < end_chainage_m`` [m] of
        the latest processings of the track's complete runs (or of ``runs``, UUIDs): the
        samples files' ``columns`` (default all, ``SAMPLE_COLUMNS``) and ``run``, a categorical
        of run UUIDs in order of start time; rows by run, scan and wire. Only the row groups
        that hold the range are read (``samples_dataset``)."""
        if not start_chainage_m < end_chainage_m:
            raise UserError(
                f"chainage range {start_chainage_m:g} m to {end_chainage_m:g} m: the start "
                "must be below the end"
            )
        wanted = list(SAMPLE_COLUMNS if columns is None else dict.fromkeys(columns))
        unknown = [c for c in wanted if c not in SAMPLE_COLUMNS]
        if unknown:
            raise UserError(f"samples column {unknown[0]!r}: one of {', '.join(SAMPLE_COLUMNS)}")
        files = self._sample_files(line, track, runs)
        dataset = self._dataset(files)
        chainage = ds.field("chainage_m")
        inside = (chainage >= start_chainage_m) & (chainage < end_chainage_m)
        try:
            table = dataset.to_table(columns=[*wanted, "run"], filter=inside)
        except (OSError, pa.ArrowInvalid) as exc:
            raise StoreError(
                f"{self.store.url}: cannot read the samples: {_one_line(exc)}"
            ) from None
        for name, value in ADDED_COLUMNS.items():
            if name in wanted:
                at = table.schema.get_field_index(name)
                table = table.set_column(at, name, table.column(name).fill_null(value))
        frame = table.to_pandas()
        order = [run for run, _ in files]
        frame["run"] = pd.Categorical(frame["run"], categories=order, ordered=True)
        by = ["run", *(c for c in ("scan", "wire") if c in wanted)]
        return frame.sort_values(by, kind="stable", ignore_index=True)
