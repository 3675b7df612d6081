"""The analysts' API (``catenary.fleet.analysts``): DataFrames of runs, spans, histories,
alerts and samples from a real database (SQLite and PostgreSQL) and a real store (a folder,
and S3 through ``rclone serve s3``)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest
from sqlalchemy.engine import Engine

from catenary.config import Settings, load_settings
from catenary.errors import UserError
from catenary.fleet.analysts import (
    ALERT_COLUMNS,
    HISTORY_COLUMNS,
    RUN_COLUMNS,
    SAMPLE_COLUMNS,
    SPAN_FRAME_COLUMNS,
    FleetData,
)
from catenary.measurement.samples import SAMPLES_SCHEMA, SampleWriter
from catenary.storage.database import session_scope
from catenary.storage.models import MaintenanceAction, Track
from catenary.storage.store import Store, StoreError, open_store, samples_key

from ..conftest import Build

T0 = Build.T0
ROWS = 40_000  # two row groups of 16,384 and a shorter third
LEGACY_KEY = "samples/run-2-1f2e3d4c.parquet"


def write_samples(
    store: Store, folder: Path, key: str, thickness_mm: float, *, decreasing: bool, v1: bool
) -> None:
    """A samples file of ``ROWS`` scans over chainage 1000 m to 1100 m (the other way when
    ``decreasing``), one wire of ``thickness_mm``, put at ``key``; ``v1``: without
    ``selection_uncertain`` (a version 1 file)."""
    chainage = np.linspace(1000.0, 1100.0, ROWS)
    columns = {
        "scan": np.arange(ROWS, dtype=np.int64),
        "position_m": chainage - 1000.0,
        "chainage_m": chainage[::-1] if decreasing else chainage,
        "wire": np.zeros(ROWS, dtype=np.int32),
        "height_mm": np.full(ROWS, 5300.0),
        "stagger_mm": np.zeros(ROWS),
        "wear_width_mm": np.full(ROWS, 6.0),
        "residual_thickness_mm": np.full(ROWS, thickness_mm),
        "selection_uncertain": np.zeros(ROWS, dtype=bool),
        "cameras": np.full(ROWS, 3, dtype=np.int16),
        "span": np.zeros(ROWS, dtype=np.int32),
        "vehicle_fault": np.zeros(ROWS, dtype=bool),
    }
    schema = pa.schema([f for f in SAMPLES_SCHEMA if not (v1 and f.name == "selection_uncertain")])
    local = folder / key.replace("/", "_")
    with SampleWriter(local, schema) as writer:
        writer.write(columns)
    store.put_file(local, key)


@dataclass(frozen=True)
class Fleet:
    config: Path
    database_url: str
    first: str  # run UUIDs: increasing, two processings
    second: str  # decreasing, a legacy samples key, after a repair
    latest_processing: str


def stock(engine: Engine, store: Store, folder: Path, config: Path, database_url: str) -> Fleet:
    """Two complete runs of L100 track 1 (and an empty track 2): the first processed twice
    (10.5 mm then 10.0 mm), the second after the wire's replacement (12.0 mm, its samples under
    a key from before the store), two wires in span 0 and an alert each."""
    with session_scope(engine) as session:
        first = Build.run(session, status="complete", length_m=100.0)
        old = first.processing
        assert old is not None
        session.add(Build.span(first, min_residual_thickness_mm=10.5))
        old.samples_key = samples_key("L100", "1", first.uuid, old.uuid)
        write_samples(store, folder, old.samples_key, 10.5, decreasing=False, v1=False)
        latest = Build.processing(first, processed_at=T0 + timedelta(hours=1), length_m=100.0)
        first.processing = latest
        session.flush()
        key = samples_key("L100", "1", first.uuid, latest.uuid)
        latest.samples_key = key
        write_samples(store, folder, key, 10.0, decreasing=False, v1=False)
        # an overlap in span 0: wire 0 on the left (looking toward increasing chainage)
        session.add_all(
            [
                Build.span(
                    first,
                    min_residual_thickness_mm=10.0,
                    stagger_min_mm=-300.0,
                    stagger_max_mm=-100.0,
                ),
                Build.span(
                    first,
                    wire=1,
                    min_residual_thickness_mm=9.0,
                    stagger_min_mm=100.0,
                    stagger_max_mm=300.0,
                ),
            ]
        )
        session.add(Track(line=first.line, code="2"))
        session.add(
            MaintenanceAction(
                track=first.track,
                kind="wire_replaced",
                from_chainage_m=990.0,
                to_chainage_m=1060.0,
                performed_at=T0 + timedelta(days=10),
                recorded_by="planner",
            )
        )
        second = Build.run(
            session,
            line=first.line,
            track=first.track,
            vehicle=first.vehicle,
            rig_calibration=first.rig_calibration,
            source_sha256="e" * 64,
            direction="decreasing",
            started_at=T0 + timedelta(days=30),
            status="complete",
            samples_key=LEGACY_KEY,
        )
        write_samples(store, folder, LEGACY_KEY, 12.0, decreasing=True, v1=True)
        # decreasing: the run's wire 0, right in its own frame, is on the line's left
        session.add_all(
            [
                Build.span(
                    second,
                    min_residual_thickness_mm=12.0,
                    stagger_min_mm=100.0,
                    stagger_max_mm=300.0,
                ),
                Build.span(
                    second,
                    wire=1,
                    min_residual_thickness_mm=11.5,
                    stagger_min_mm=-300.0,
                    stagger_max_mm=-100.0,
                ),
            ]
        )
        assert first.track is not None
        session.add_all(
            [
                Build.alert(first.track, "a", raised_at=T0, status="open"),
                Build.alert(
                    first.track,
                    "b",
                    raised_at=T0 + timedelta(days=1),
                    status="resolved",
                    resolved_at=T0 + timedelta(days=30),
                    resolved_by_run=second,
                    details={"rate_mm_per_year": 0.25},
                ),
            ]
        )
        session.flush()
        return Fleet(config, database_url, first.uuid, second.uuid, latest.uuid)


@pytest.fixture
def fleet(engine: Engine, database_url: str, tmp_path: Path) -> Fleet:
    config = tmp_path / "fleet.toml"
    config.write_text("")
    settings = load_settings(config_path=config, database_url=database_url)
    return stock(engine, open_store(settings), tmp_path, config, database_url)


@pytest.fixture
def data(fleet: Fleet) -> Iterator[FleetData]:
    with FleetData.open(fleet.config, database_url=fleet.database_url) as opened:
        yield opened


def dtypes(frame: pd.DataFrame) -> dict[str, str]:
    return {name: str(dtype) for name, dtype in frame.dtypes.items()}


def test_runs(data: FleetData, fleet: Fleet) -> None:
    runs = data.runs()
    assert list(runs["uuid"]) == [fleet.first, fleet.second]  # by start time
    assert list(runs.columns) == list(RUN_COLUMNS)
    first = runs.iloc[0]
    assert first["started_at"] == pd.Timestamp(T0)
    assert str(runs["started_at"].dtype) == "datetime64[us, UTC]"
    assert (first["line"], first["track"], first["direction"]) == ("L100", "1", "increasing")
    assert (first["vehicle"], first["status"]) == ("demo-rig", "complete")
    assert first["processing"] == fleet.latest_processing
    assert first["processed_at"] == pd.Timestamp(T0 + timedelta(hours=1))
    assert first["length_m"] == pytest.approx(100.0)
    assert first["samples_key"].endswith(f"/run={fleet.first}/{fleet.latest_processing}.parquet")
    assert runs.iloc[1]["samples_key"] == LEGACY_KEY
    assert list(data.runs("L100", "1")["uuid"]) == [fleet.first, fleet.second]
    assert dtypes(runs) == RUN_COLUMNS
    empty = data.runs("L100", "2")
    assert empty.empty and dtypes(empty) == RUN_COLUMNS


def test_spans_of_the_latest_processings(data: FleetData, fleet: Fleet) -> None:
    spans = data.spans("L100")
    assert dtypes(spans) == SPAN_FRAME_COLUMNS
    # the first run's first processing (10.5 mm) is not seen
    seen = zip(spans["run"], spans["wire"], spans["min_residual_thickness_mm"], strict=True)
    assert list(seen) == [
        (fleet.first, 0, 10.0),
        (fleet.first, 1, 9.0),
        (fleet.second, 0, 12.0),
        (fleet.second, 1, 11.5),
    ]
    row = spans.iloc[0]
    assert (row["track"], row["direction"], row["vehicle"]) == ("1", "increasing", "demo-rig")
    assert (row["mast_from"], row["mast_to"], row["span"]) == ("M1", "M2", 0)
    assert (row["start_chainage_m"], row["end_chainage_m"]) == (1000.0, 1050.0)
    assert row["samples"] == 2500 and row["started_at"] == pd.Timestamp(T0)
    later = data.spans("L100", "1", since=T0 + timedelta(days=1))
    assert set(later["run"]) == {fleet.second}
    earlier = data.spans("L100", "1", until=T0 + timedelta(days=30))
    assert set(earlier["run"]) == {fleet.first}
    assert data.spans("L100", "2").empty
    with pytest.raises(UserError, match="timezone"):
        data.spans("L100", since=datetime(2024, 1, 1))


def test_span_histories_by_stretch_position_and_time(data: FleetData, fleet: Fleet) -> None:
    history = data.span_histories("L100", "1")
    assert list(history.columns) == list(HISTORY_COLUMNS)
    assert dtypes(history) == HISTORY_COLUMNS
    got = list(
        zip(
            history["position"],
            history["run"],
            history["min_residual_thickness_mm"],
            history["since_repair"],
            strict=True,
        )
    )
    # position 0 is the line's left wire whichever way the run went; the first run came
    # before the wire's replacement
    assert got == [
        (0, fleet.first, 10.0, False),
        (0, fleet.second, 12.0, True),
        (1, fleet.first, 9.0, False),
        (1, fleet.second, 11.5, True),
    ]
    assert set(history["mast_from"]) == {"M1"} and set(history["mast_to"]) == {"M2"}
    assert list(history["wire"]) == [0, 0, 1, 1]
    assert set(history["wire_type"]) == {"CTA120"}
    assert (
        list(history["started_at"]) == [pd.Timestamp(T0), pd.Timestamp(T0 + timedelta(days=30))] * 2
    )
    assert data.span_histories("L100", "2").empty


def test_alerts(data: FleetData, fleet: Fleet) -> None:
    alerts = data.alerts()
    assert dtypes(alerts) == ALERT_COLUMNS
    assert list(alerts["condition_key"]) == ["a", "b"]
    assert set(alerts["line"]) == {"L100"} and set(alerts["track"]) == {"1"}
    resolved = data.alerts(status="resolved")
    assert list(resolved["condition_key"]) == ["b"]
    row = resolved.iloc[0]
    assert row["resolved_by_run"] == fleet.second
    assert row["resolved_at"] == pd.Timestamp(T0 + timedelta(days=30))
    assert row["details"] == {"rate_mm_per_year": 0.25}
    assert (row["value"], row["threshold"]) == (9.9, 10.0)
    assert pd.isna(alerts.iloc[0]["resolved_by_run"])
    assert len(data.alerts(line="L100", track="1")) == 2
    assert data.alerts(line="L100", track="2").empty
    with pytest.raises(UserError, match="'closed': one of open, acknowledged, resolved"):
        data.alerts(status="closed")


def test_unknown_line_or_track_is_a_user_error(data: FleetData) -> None:
    with pytest.raises(UserError, match=r"line 'L999' is not in the database \(lines: L100\)"):
        data.spans("L999")
    with pytest.raises(UserError, match=r"line 'L100' has no track '3' \(tracks: 1, 2\)"):
        data.samples("L100", "3", 0.0, 1.0)
    with pytest.raises(UserError, match="give its line"):
        data.runs(track="1")


def whole(store: Store, key: str) -> pd.DataFrame:
    return pq.read_table(store.filesystem.open_input_file(key)).to_pandas()


def check_range(data: FleetData, fleet: Fleet, start_m: float, end_m: float) -> None:
    """The samples in [start_m, end_m) of both runs are exactly the files' rows there."""
    samples = data.samples("L100", "1", start_m, end_m)
    assert list(samples.columns) == [*SAMPLE_COLUMNS, "run"]
    assert list(samples["run"].cat.categories) == [fleet.first, fleet.second]
    runs = data.runs("L100", "1").set_index("uuid")["samples_key"]
    for run, thickness in ((fleet.first, 10.0), (fleet.second, 12.0)):
        rows = samples[samples["run"] == run]
        file = whole(data.store, runs[run])
        inside = file[(file["chainage_m"] >= start_m) & (file["chainage_m"] < end_m)]
        assert len(inside) > 0
        assert list(rows["scan"]) == sorted(inside["scan"])
        assert np.array_equal(
            rows["chainage_m"].to_numpy(), inside.sort_values("scan")["chainage_m"].to_numpy()
        )
        assert set(rows["residual_thickness_mm"]) == {thickness}  # the latest processing's
        assert not rows["selection_uncertain"].any()  # the version 1 file's too
    assert samples["chainage_m"].min() >= start_m and samples["chainage_m"].max() < end_m


def test_samples_of_a_chainage_range(data: FleetData, fleet: Fleet) -> None:
    check_range(data, fleet, 1020.0, 1030.0)
    only = data.samples("L100", "1", 1020.0, 1020.5, runs=[fleet.second], columns=["chainage_m"])
    assert list(only.columns) == ["chainage_m", "run"]
    file = whole(data.store, LEGACY_KEY)
    assert set(only["run"]) == {fleet.second}
    assert len(only) == np.count_nonzero(
        (file["chainage_m"] >= 1020.0) & (file["chainage_m"] < 1020.5)
    )
    assert data.samples("L100", "1", 2000.0, 2100.0).empty
    assert data.samples("L100", "2", 1000.0, 1100.0).empty
    with pytest.raises(UserError, match="column 'thickness'"):
        data.samples("L100", "1", 1000.0, 1010.0, columns=["thickness"])
    with pytest.raises(UserError, match="start must be below the end"):
        data.samples("L100", "1", 1010.0, 1000.0)
    with pytest.raises(UserError, match="run 0000 is not a complete run"):
        data.samples("L100", "1", 1000.0, 1010.0, runs=["0000"])


def test_a_missing_samples_object_is_a_one_line_error(data: FleetData) -> None:
    data.store.delete(LEGACY_KEY)
    with pytest.raises(StoreError, match=f"cannot (open|read) the samples: .*{LEGACY_KEY}") as err:
        data.samples("L100", "1", 1000.0, 1010.0)
    assert "\n" not in str(err.value)


def test_a_range_reads_only_its_row_groups(data: FleetData, fleet: Fleet) -> None:
    key = data.runs("L100", "1")["samples_key"].iloc[0]
    metadata = pq.ParquetFile(data.store.filesystem.open_input_file(key)).metadata
    assert metadata.num_row_groups == 3
    chainage = metadata.schema.to_arrow_schema().get_field_index("chainage_m")
    for group in range(metadata.num_row_groups):
        assert metadata.row_group(group).column(chainage).statistics.has_min_max
    dataset = data.samples_dataset("L100", "1")
    inside = (ds.field("chainage_m") >= 1020.0) & (ds.field("chainage_m") < 1030.0)
    groups = [len(f.split_by_row_group(inside)) for f in dataset.get_fragments(filter=inside)]
    assert groups == [1, 1]  # of 3 each


def test_samples_in_an_s3_store(
    engine: Engine, database_url: str, s3_settings: Settings, tmp_path: Path
) -> None:
    assert s3_settings.config_path is not None
    fleet = stock(engine, open_store(s3_settings), tmp_path, s3_settings.config_path, database_url)
    with FleetData.open(fleet.config, database_url=database_url) as data:
        assert data.store.url.startswith("s3://")
        check_range(data, fleet, 1040.0, 1041.0)


def test_opening_a_missing_database_is_a_user_error(tmp_path: Path) -> None:
    missing = tmp_path / "none.sqlite"
    with pytest.raises(UserError, match=r"none\.sqlite") as err:
        FleetData.open(database_url=f"sqlite:///{missing}")
    assert "\n" not in str(err.value)
    assert not missing.exists()
    with pytest.raises(UserError, match="config file not found"):
        FleetData.open(tmp_path / "nowhere.toml")
