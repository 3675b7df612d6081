"""Envelope levels of a run's samples: exact minima and maxima per 1, 10 and 100 m, nested;
written when a run is stored; read by the track view at the level that fills the screen."""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner
from sqlalchemy import create_engine, func, select
from sqlalchemy.orm import Session

from catenary.cli import cli
from catenary.config import Settings
from catenary.errors import UserError
from catenary.measurement import envelope as envelopes
from catenary.measurement.envelope import (
    LEVELS_M,
    QUANTITIES,
    RAW_BELOW_M,
    choose_level,
    ensure_envelopes,
    envelope_bytes,
    envelope_levels,
    track_view,
)
from catenary.measurement.samples import SampleWriter, StoredSamples, read_sample_batches
from catenary.storage.models import Run
from catenary.storage.store import Store, envelope_key, open_store, samples_key

Columns = dict[str, np.ndarray[Any, Any]]


def synthetic_samples(length_m: float, step_m: float, seed: int = 7) -> Columns:
    """Two wires along ``[0, length_m]`` in scan order (as ``process`` writes them), a few
    NaN widths, vehicle faults and uncertain selections; the samples file's columns."""
    rng = np.random.default_rng(seed)
    scans = int(length_m / step_m)
    chainage = np.repeat(np.arange(scans) * step_m + rng.uniform(0.0, step_m, scans), 2)
    rows = chainage.shape[0]
    thickness = rng.normal(11.0, 0.4, rows)
    thickness[rng.random(rows) < 0.02] = np.nan  # no width at a fitting
    return {
        "scan": np.repeat(np.arange(scans), 2),
        "position_m": chainage,
        "chainage_m": chainage,
        "wire": np.tile(np.array([0, 1], dtype=np.int32), scans),
        "height_mm": rng.normal(5300.0, 20.0, rows),
        "stagger_mm": rng.normal(0.0, 150.0, rows),
        "wear_width_mm": rng.normal(6.0, 0.5, rows),
        "residual_thickness_mm": thickness,
        "selection_uncertain": rng.random(rows) < 0.01,
        "cameras": np.full(rows, 3, dtype=np.int16),
        "span": np.full(rows, -1, dtype=np.int32),
        "vehicle_fault": rng.random(rows) < 0.01,
    }


def write_samples(path: Path, columns: Columns) -> Path:
    with SampleWriter(path) as writer:
        writer.write(columns)
    return path


def brute_force(columns: Columns, level_m: float) -> dict[tuple[int, int], tuple[Any, ...]]:
    """(wire, bin) -> count and each quantity's (min, max), one sample at a time."""
    found: dict[tuple[int, int], list[Any]] = {}
    good = ~columns["vehicle_fault"] & ~columns["selection_uncertain"]
    for i in np.flatnonzero(good):
        key = (int(columns["wire"][i]), math.floor(columns["chainage_m"][i] / level_m))
        entry = found.setdefault(key, [0, *([math.inf, -math.inf] * len(QUANTITIES))])
        entry[0] += 1
        for k, q in enumerate(QUANTITIES):
            value = float(columns[q][i])
            if not math.isnan(value):
                entry[1 + 2 * k] = min(entry[1 + 2 * k], value)
                entry[2 + 2 * k] = max(entry[2 + 2 * k], value)
    return {
        key: tuple(v if math.isfinite(v) else math.nan for v in entry)
        for key, entry in found.items()
    }


def table_rows(table: Any, level_m: float) -> dict[tuple[int, int], tuple[Any, ...]]:
    names = ["count", *(f"{side}_{q}" for q in QUANTITIES for side in ("min", "max"))]
    rows = table.filter(table["level_m"].to_numpy() == level_m).to_pydict()
    return {
        (wire, math.floor(c / level_m)): tuple(rows[n][i] for n in names)
        for i, (wire, c) in enumerate(zip(rows["wire"], rows["chainage_m"], strict=True))
    }


def same(a: dict[Any, tuple[Any, ...]], b: dict[Any, tuple[Any, ...]]) -> bool:
    """Equal, NaN equal to NaN (exactly: a minimum is a sample's value)."""
    return a.keys() == b.keys() and all(
        np.array_equal(np.array(a[k], float), np.array(b[k], float), equal_nan=True) for k in a
    )


def folder_store(tmp_path: Path) -> Store:
    return open_store(Settings(database_url="sqlite://", data_dir=tmp_path / "store"))


def stored_samples(tmp_path: Path, columns: Columns) -> tuple[Store, str]:
    store = folder_store(tmp_path)
    key = samples_key("demo line", "1", "run", "processing")
    store.put_file(write_samples(tmp_path / "samples.parquet", columns), key)
    return store, key


def test_levels_are_the_exact_minima_and_maxima_of_a_brute_force_pass(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # shuffled rows, negative chainage: nothing relies on the file's order
    columns = synthetic_samples(3000.0, 0.3)
    order = np.random.default_rng(1).permutation(columns["chainage_m"].shape[0])
    columns = {name: values[order] for name, values in columns.items()}
    columns["chainage_m"] = columns["chainage_m"] - 123.4
    monkeypatch.setattr(envelopes, "MERGE_ROWS", 500)  # merges on the way, not only at the end
    path = write_samples(tmp_path / "samples.parquet", columns)
    assert pq.ParquetFile(path).num_row_groups > 1
    output = tmp_path / "envelopes.parquet"
    output.write_bytes(envelope_bytes(path))
    table = pq.read_table(output)
    assert table.schema.metadata[b"format"] == b"catenary-envelopes"
    for level_m in LEVELS_M:
        assert same(table_rows(table, level_m), brute_force(columns, level_m)), level_m
    # the rows sorted by level, then chainage
    keys = np.column_stack([table["level_m"].to_numpy(), table["chainage_m"].to_numpy()])
    assert (np.diff(keys[:, 0]) >= 0).all()
    same_level = np.diff(keys[:, 0]) == 0
    assert (np.diff(keys[:, 1])[same_level] >= 0).all()


def test_levels_nest_each_coarse_bin_gathers_its_finer_ones() -> None:
    columns = synthetic_samples(2500.0, 0.7, seed=11)
    values = {q: columns[q] for q in QUANTITIES}
    levels = envelope_levels(columns["chainage_m"], columns["wire"], values)
    assert [b.bin_m for b in levels] == list(LEVELS_M)
    for fine, coarse in itertools.pairwise(levels):
        assert (np.mod(coarse.chainage_m, coarse.bin_m) == 0).all()
        factor = round(coarse.bin_m / fine.bin_m)
        for i in range(coarse.wire.shape[0]):
            inside = (fine.wire == coarse.wire[i]) & (fine.index // factor == coarse.index[i])
            assert fine.count[inside].sum() == coarse.count[i]
            for q in QUANTITIES:
                assert np.nanmin(fine.low[q][inside]) == coarse.low[q][i]
                assert np.nanmax(fine.high[q][inside]) == coarse.high[q][i]
    assert levels[0].count.sum() == columns["chainage_m"].shape[0]


@pytest.mark.parametrize(
    ("width_m", "columns", "level_m"),
    [
        (100_000.0, 1000, 100.0),  # 100 m a column
        (99_999.0, 1000, 10.0),  # a hair under 100 m a column: 10 m bins
        (50_000.0, 1000, 10.0),
        (5_000.0, 1000, 1.0),
        (1_500.0, 1100, 1.0),  # 1.4 m a column
        (2_000.0, 4000, 1.0),  # half a metre a column: the finest there is
        (20_000.0, 100, 100.0),  # 200 m a column: still the coarsest
        (RAW_BELOW_M, 1000, 1.0),
        (RAW_BELOW_M - 0.01, 1000, None),  # raw below a kilometre
        (500.0, 10, None),
    ],
)
def test_the_coarsest_level_that_gives_each_pixel_column_a_bin(
    width_m: float, columns: int, level_m: float | None
) -> None:
    assert choose_level(1234.5, 1234.5 + width_m, columns) == level_m


def test_track_view_reads_the_window_at_its_level_and_builds_a_missing_file(
    tmp_path: Path,
) -> None:
    columns = synthetic_samples(20_000.0, 0.25)
    store, key = stored_samples(tmp_path, columns)
    assert not store.exists(envelope_key(key))  # a processing stored before envelope files
    view = track_view(store, key, 4321.0, 9321.0, 1000)  # 5 m a column: 1 m bins
    assert store.exists(envelope_key(key)) and ensure_envelopes(store, key) == envelope_key(key)
    assert view.level_m == 1.0 and not view.raw and sorted(view.wires) == [0, 1]
    expected = brute_force(columns, 1.0)
    for wire, trace in view.wires.items():
        bins = [k[1] for k in expected if k[0] == wire and 4321 - 1 < k[1] <= 9321]
        np.testing.assert_array_equal(trace.chainage_m, np.array(sorted(bins), float))
        for k, q in enumerate(QUANTITIES):
            low = [expected[(wire, b)][1 + 2 * k] for b in sorted(bins)]
            high = [expected[(wire, b)][2 + 2 * k] for b in sorted(bins)]
            np.testing.assert_array_equal(trace.low[q], low)
            np.testing.assert_array_equal(trace.high[q], high)
    whole = track_view(store, key, -500.0, 20_500.0, 200, quantities=["height_mm"])
    assert whole.level_m == 100.0 and list(whole.wires[1].low) == ["height_mm"]
    assert whole.wires[0].chainage_m.tolist() == [100.0 * i for i in range(200)]


def test_track_view_below_a_kilometre_reads_the_samples_of_the_window_only(
    tmp_path: Path,
) -> None:
    columns = synthetic_samples(20_000.0, 0.25)
    store, key = stored_samples(tmp_path, columns)
    view = track_view(store, key, 7000.0, 7500.0, 1000)
    assert view.raw and view.level_m is None
    assert not store.exists(envelope_key(key))  # not needed for raw samples
    good = ~columns["vehicle_fault"] & ~columns["selection_uncertain"]
    good &= (columns["chainage_m"] >= 7000.0) & (columns["chainage_m"] <= 7500.0)
    for wire, trace in view.wires.items():
        rows = good & (columns["wire"] == wire)
        np.testing.assert_array_equal(trace.chainage_m, columns["chainage_m"][rows])
        for q in QUANTITIES:
            np.testing.assert_array_equal(trace.low[q], columns[q][rows])
            np.testing.assert_array_equal(trace.high[q], columns[q][rows])
    # 160,000 rows in 10 row groups; half a kilometre lies in one or two of them
    source = StoredSamples(store, key)
    assert len(list(read_sample_batches(source, ["chainage_m"]))) == 10
    assert len(list(read_sample_batches(source, ["chainage_m"], within_m=(7000.0, 7500.0)))) <= 2


def test_track_view_reads_an_s3_store(s3_settings: Settings, tmp_path: Path) -> None:
    columns = synthetic_samples(3000.0, 0.5)
    store = open_store(s3_settings)
    key = samples_key("demo line", "1", "run", "processing")
    store.put_file(write_samples(tmp_path / "samples.parquet", columns), key)
    binned = track_view(store, key, 0.0, 3000.0, 300)
    raw = track_view(store, key, 1000.0, 1200.0, 300)
    assert store.keys("envelopes") == [envelope_key(key)]
    assert binned.level_m == 10.0 and binned.wires[1].chainage_m.shape == (300,)
    expected = brute_force(columns, 10.0)
    assert binned.wires[1].low["height_mm"][17] == expected[(1, 17)][3]
    in_window = (columns["chainage_m"] >= 1000.0) & (columns["chainage_m"] <= 1200.0)
    good = in_window & ~columns["vehicle_fault"] & ~columns["selection_uncertain"]
    assert raw.raw and sum(w.chainage_m.shape[0] for w in raw.wires.values()) == good.sum()


def test_a_window_the_view_cannot_draw_is_one_clear_error(tmp_path: Path) -> None:
    store, key = stored_samples(tmp_path, synthetic_samples(100.0, 0.5))
    with pytest.raises(UserError, match=r"chainage window 5\.0 to 5\.0 m"):
        track_view(store, key, 5.0, 5.0, 100)
    with pytest.raises(UserError, match="columns 0"):
        track_view(store, key, 0.0, 5000.0, 0)
    with pytest.raises(UserError, match="quantity 'wear_width_mm'"):
        track_view(store, key, 0.0, 50.0, 100, quantities=["wear_width_mm"])
    store.put_bytes(b"not Parquet", envelope_key(key))
    with pytest.raises(UserError, match=r"envelopes/.*: not a readable envelope file"):
        track_view(store, key, 0.0, 5000.0, 100)


def test_process_stores_the_envelope_file_beside_the_samples(
    small_run: Any, tmp_path: Path, isolated_environment: Path
) -> None:
    database = f"sqlite:///{tmp_path / 'catenary.sqlite'}"
    assert CliRunner().invoke(cli, ["--db", database, "db", "upgrade"]).exit_code == 0
    result = CliRunner().invoke(cli, small_run.process_args(database))
    assert result.exit_code == 0, result.output
    with Session(create_engine(database)) as session:
        (run,) = session.scalars(select(Run))
        assert run.processing is not None and run.processing.samples_key
        key = run.processing.samples_key
    store = open_store(Settings(database_url=database, data_dir=isolated_environment))
    assert envelope_key(key).startswith("envelopes/line=demo-line/track=1/run=")
    table = pq.read_table(isolated_environment / envelope_key(key))
    samples = pq.read_table(isolated_environment / key).to_pydict()
    columns = {name: np.asarray(values) for name, values in samples.items()}
    for level_m in LEVELS_M:
        assert same(table_rows(table, level_m), brute_force(columns, level_m))
    assert store.keys("envelopes") == [envelope_key(key)]


def test_a_process_that_cannot_store_the_envelope_file_stores_nothing(
    small_run: Any, tmp_path: Path, isolated_environment: Path
) -> None:
    database = f"sqlite:///{tmp_path / 'catenary.sqlite'}"
    assert CliRunner().invoke(cli, ["--db", database, "db", "upgrade"]).exit_code == 0
    isolated_environment.mkdir(parents=True, exist_ok=True)
    (isolated_environment / "envelopes").write_text("a file where the folder goes")
    result = CliRunner().invoke(cli, small_run.process_args(database))
    assert result.exit_code == 1 and "envelopes/line=demo-line" in result.output
    with Session(create_engine(database)) as session:
        assert session.scalar(select(func.count()).select_from(Run)) == 0
    store = open_store(Settings(database_url=database, data_dir=isolated_environment))
    assert store.keys("samples") == [] and store.keys("evidence") == []
