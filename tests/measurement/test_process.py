"""``catenary process``, ``export`` and ``compare`` end to end on a simulated run.

The run is simulated with its ground truth and mast register, the rig calibrated from
simulated captures (as a user would), and the real CLI processes it into a fresh database,
on SQLite and on PostgreSQL. Results are checked against the truth with physical
tolerances: residual thickness within 0.1 mm (the processor's worst case), chainage within
the alignment's tolerance, spans cut at the register's masts.
"""

from __future__ import annotations

import csv
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import uuid
import warnings
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import h5py
import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner, Result
from sqlalchemy import Engine, create_engine, event, func, select
from sqlalchemy.orm import Session

from catenary.cli import cli
from catenary.config import Settings
from catenary.domain import WireObservations
from catenary.errors import UserError
from catenary.measurement.evidence import evidence_key
from catenary.measurement.process import (
    LEGACY_SCRATCH_AGE_S,
    database_fingerprint,
    file_sha256,
    remove_abandoned_scratch,
)
from catenary.measurement.runfile import RunFileWarning
from catenary.measurement.samples import EXPORT_COLUMNS
from catenary.measurement.spans import SPAN_COLUMNS
from catenary.plugins import PluginRegistry, Processor, hookimpl
from catenary.storage import migrate
from catenary.storage.database import make_engine, session_scope
from catenary.storage.models import Mast, Run, SpanMeasurement, run_uuid
from catenary.storage.store import envelope_key, open_store, samples_key
from catenary_linescan.simulator import DEMO_RIG_PATH, load_rig, record_run
from catenary_linescan.simulator.captures import write_captures

pytestmark = pytest.mark.slow

CHAINAGE_TOLERANCE_M = 0.3
"""Aligned chainage against the truth: the registration points' positions are known to a
decimetre or two, and the fit averages them."""

THICKNESS_TOLERANCE_MM = 0.1
"""Residual thickness against the truth, worst sample (the processor's target)."""


@dataclass(frozen=True)
class Simulated:
    run: Path
    truth: Path
    masts: Path
    rig: Path


def invoke(*args: str) -> Result:
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


SETTINGS = {
    "length_m": 250.0,
    "overlap": True,
    "speed_kmh": 160.0,
    "seed": 5,
    # the noisiest sensors the 2 mm target covers (issue 14): 0.3 mm at 100 Hz
    "sensor_noise_mm": 0.3,
    "sensor_rate_hz": 100.0,
}

POSITION_TOLERANCE_MM = 2.0
"""Height and stagger against the truth, worst sample (the processor's target)."""
ENCODER_ERRORS = {"encoder_scale_error": 0.004, "start_chainage_error_m": -2.5}


@pytest.fixture(scope="module")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> Simulated:
    """The run with a 0.4 % encoder scale error and a start chainage 2.5 m off."""
    folder = tmp_path_factory.mktemp("simulated")
    run = folder / "run.h5"
    record_run(run, {**SETTINGS, **ENCODER_ERRORS})
    captures, _ = write_captures(folder / "captures.h5", load_rig(DEMO_RIG_PATH), seed=2)
    rig = folder / "rig.toml"
    result = invoke("calibrate", captures, "--vehicle", DEMO_RIG_PATH, "-o", rig)
    assert result.exit_code == 0, result.output
    return Simulated(run, run.with_suffix(".truth.h5"), run.with_suffix(".masts.csv"), rig)


@pytest.fixture
def database(database_url: str) -> str:
    engine = make_engine(database_url)
    migrate.upgrade(engine)
    engine.dispose()
    return database_url


def process(simulated: Simulated, database: str, *options: str) -> Result:
    return invoke(
        "process", simulated.run, "--rig", simulated.rig, "--masts", simulated.masts,
        "--db", database, *options,
    )  # fmt: skip


def one_line_error(result: Result) -> str:
    assert result.exit_code == 1, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.output
    return lines[0]


def stored(database: str) -> tuple[int, int]:
    with Session(create_engine(database)) as session:
        runs = session.scalar(select(func.count()).select_from(Run))
        spans = session.scalar(select(func.count()).select_from(SpanMeasurement))
    return int(runs or 0), int(spans or 0)


def samples_of(database: str, data_dir: Path, run_id: int) -> dict[str, np.ndarray]:
    with Session(create_engine(database)) as session:
        run = session.get(Run, run_id)
        assert run is not None and run.processing is not None and run.processing.samples_key
        table = pq.read_table(data_dir / run.processing.samples_key)
    return {name: table.column(name).to_numpy() for name in table.column_names}


def thickness_error(
    samples: dict[str, np.ndarray], truth: dict[str, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """Whether each sample lies on a contact wire (within 10 mm of stagger of the nearest at
    its scan), and the residual thickness error [mm] of those on a running one, without a
    vehicle fault."""
    scan = samples["scan"]
    distance = np.abs(truth["stagger_mm"][scan] - samples["stagger_mm"][:, None])
    distance = np.where(truth["contact"] & truth["present"][scan], distance, np.inf)
    nearest = np.argmin(distance, axis=1)
    on_wire = distance[np.arange(scan.shape[0]), nearest] < 10.0
    error = samples["residual_thickness_mm"] - truth["thickness"][scan, nearest]
    good = on_wire & truth["running"][scan, nearest] & ~samples["vehicle_fault"]
    return on_wire, error[good]


def truth_of(path: Path) -> dict[str, np.ndarray]:
    with h5py.File(path, "r") as f:
        return {
            "chainage_m": f["/scans/chainage_m"][:],
            "stagger_mm": f["/wires/stagger_mm"][:],
            "height_mm": f["/wires/height_mm"][:],
            "running": f["/wires/running"][:],
            "present": f["/wires/present"][:],
            "contact": f["/wires/contact"][:],
            "thickness": f["/wires/residual_thickness_mm"][:],
        }


def test_a_run_is_stored_with_its_spans_and_samples_against_the_truth(
    simulated: Simulated, database: str, isolated_environment: Path
) -> None:
    result = process(simulated, database)
    assert result.exit_code == 0, result.output
    assert re.fullmatch(
        r"stored as run 1 \(UUID [0-9a-f-]{36}\), processing [0-9a-f-]{36}",
        result.output.strip().splitlines()[-1],
    )
    assert "aligned to the register" in result.output
    with Session(create_engine(database)) as session:
        run = session.get(Run, 1)
        assert run is not None
        assert (run.line.code, run.track.code if run.track else None) == ("demo-line", "1")
        assert run.status == "complete" and run.vehicle.name == "demo-rig"
        assert run.rig_calibration.version == 1
        assert run.uuid == run_uuid(file_sha256(simulated.run), file_sha256(simulated.rig))
        assert run.uuid in result.output
        made = run.processing
        assert made is not None and made.processor == "linescan-stereo"
        assert made.settings == {
            "processor_options": {},
            "vehicle_filter_hz": 5.0,
            "wire_type": None,
        }
        assert made.chainage_aligned and made.alignment_matched and made.alignment_matched >= 3
        # chainage per encoder metre: the encoder reads the simulated 0.4 % long
        assert made.encoder_scale == pytest.approx(1 / 1.004, abs=0.001)
        masts = {m.code: m.chainage_m for m in session.scalars(select(Mast))}
        spans = list(run.span_measurements)
    samples = samples_of(database, isolated_environment, 1)
    truth = truth_of(simulated.truth)
    scan = samples["scan"]
    # chainage: aligned to the register despite the encoder's 0.4 % and the 2.5 m start error
    chainage_error = samples["chainage_m"] - truth["chainage_m"][scan]
    assert np.max(np.abs(chainage_error)) < CHAINAGE_TOLERANCE_M
    # each sample is the contact wire nearest it at its scan (none is a messenger, a dropper)
    on_wire, error = thickness_error(samples, truth)
    assert np.mean(on_wire) > 0.999
    assert np.nanmax(np.abs(error)) < THICKNESS_TOLERANCE_MM
    # spans: from one register mast to the next, each minimum that of its samples
    assert len(spans) >= 4
    # wire positions: left to right looking toward increasing chainage (this run's way)
    by_span: dict[int, list[Any]] = {}
    for s in spans:
        by_span.setdefault(s.span, []).append(s)
    assert any(len(wires) == 2 for wires in by_span.values())  # the overlap
    for wires in by_span.values():
        ordered = sorted(wires, key=lambda s: s.stagger_min_mm + s.stagger_max_mm)
        assert [s.wire_position for s in ordered] == list(range(len(wires)))
    for row in spans:
        assert masts[row.mast_from] == row.start_chainage_m
        assert masts[row.mast_to] == row.end_chainage_m
        rows = (samples["span"] == row.span) & (samples["wire"] == row.wire)
        rows &= ~samples["vehicle_fault"]
        assert row.samples == np.count_nonzero(rows)
        assert row.min_residual_thickness_mm == pytest.approx(
            np.nanmin(samples["residual_thickness_mm"][rows]), abs=1e-9
        )
        assert row.start_chainage_m <= row.min_at_chainage_m < row.end_chainage_m
    # the overlap: two contact wires in one span at least
    per_span = {}
    for row in spans:
        per_span.setdefault(row.span, set()).add(row.wire)
    assert max(len(w) for w in per_span.values()) == 2


def test_heights_and_staggers_are_within_2_mm_of_the_truth_with_noisy_sensors(
    simulated: Simulated, database: str, isolated_environment: Path
) -> None:
    """Sensors of 0.3 mm at 100 Hz: each scan's roll noise, through the 4-5 m from the sensors
    to the wire, would be 1.2 mm RMS of stagger unsmoothed (4-5 mm at worst); smoothed below
    5 Hz without lag, every sample is within 2 mm, and the summary gives the noise."""
    result = process(simulated, database)
    assert result.exit_code == 0, result.output
    samples = samples_of(database, isolated_environment, 1)
    truth = truth_of(simulated.truth)
    scan = samples["scan"]
    distance = np.abs(truth["stagger_mm"][scan] - samples["stagger_mm"][:, None])
    distance = np.where(truth["contact"] & truth["present"][scan], distance, np.inf)
    nearest = np.argmin(distance, axis=1)
    rows = np.arange(scan.shape[0])
    good = (distance[rows, nearest] < 20.0) & truth["running"][scan, nearest]
    good &= ~samples["vehicle_fault"]
    assert np.count_nonzero(good) > 5000
    stagger_error = samples["stagger_mm"][good] - truth["stagger_mm"][scan, nearest][good]
    height_error = samples["height_mm"][good] - truth["height_mm"][scan, nearest][good]
    assert np.max(np.abs(stagger_error)) < POSITION_TOLERANCE_MM
    assert np.max(np.abs(height_error)) < POSITION_TOLERANCE_MM
    (sensors,) = [line for line in result.output.splitlines() if line.startswith("sensors")]
    noise = re.fullmatch(
        r"sensors    sampled at 100 Hz, low-pass 5 Hz \(zero phase\); noise left (\S+), "
        r"right (\S+), lateral (\S+) mm RMS",
        sensors,
    )
    assert noise is not None, sensors
    np.testing.assert_allclose([float(v) for v in noise.groups()], 0.3, rtol=0.1)


def test_processing_twice_says_so_and_replace_replaces(
    simulated: Simulated, database: str, isolated_environment: Path
) -> None:
    assert process(simulated, database).exit_code == 0
    first = stored(database)
    again = process(simulated, database)
    assert again.exit_code == 0, again.output
    assert "already stored" in again.output and "run 1" in again.output
    assert stored(database) == first
    (old_file,) = (isolated_environment / "samples").rglob("*.parquet")
    replaced = process(simulated, database, "--replace")
    assert replaced.exit_code == 0, replaced.output
    assert replaced.output.strip().splitlines()[-1].startswith("stored as run 1 ")  # the same
    # a new processing, the one seen; the first is kept as it was, unseen
    with Session(create_engine(database)) as session:
        run = session.get_one(Run, 1)
        first_processing, latest = run.processings
        assert run.processing is latest
        assert latest.processed_at > first_processing.processed_at
        assert len(run.span_measurements) == first[1]
        assert {s.processing_id for s in run.span_measurements} == {latest.id}
        assert len(first_processing.span_measurements) == first[1]
        assert first_processing.samples_key == str(old_file.relative_to(isolated_environment))
        new_key = latest.samples_key
    assert stored(database) == (1, 2 * first[1])
    files = sorted((isolated_environment / "samples").rglob("*.parquet"))
    assert old_file in files and len(files) == 2
    assert new_key is not None and (isolated_environment / new_key).is_file()


def test_without_a_register_spans_come_from_the_turning_points(
    simulated: Simulated, database: str
) -> None:
    result = invoke(
        "process", simulated.run, "--rig", simulated.rig, "--wire-type", "CTA120", "--db", database
    )
    assert result.exit_code == 0, result.output
    with Session(create_engine(database)) as session:
        spans = list(session.scalars(select(SpanMeasurement)))
    with simulated.masts.open() as handle:
        register = np.array(sorted(float(row["chainage_m"]) for row in csv.DictReader(handle)))
    assert all(row.mast_from is None for row in spans)
    inner = sorted({row.start_chainage_m for row in spans})[1:]  # the first starts at the run
    assert len(inner) >= 3
    # each turning point is a registration, near a mast of the register (the encoder's
    # 0.4 % and the start error: a few metres over this run)
    offset = np.array([np.min(np.abs(register - c)) for c in inner])
    assert np.all(offset < 4.0)


def write(path: Path, text: str | bytes) -> Path:
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text)
    return path


@pytest.mark.parametrize(
    ("case", "expected"),
    [
        ("run-not-hdf5", "run.h5"),
        ("rig-not-toml", "rig.toml"),
        ("rig-missing", "no such file"),
        ("register-bad-chainage", "row 3: chainage_m = 'x' is not a finite number"),
        ("register-other-line", "no masts for line 'demo-line' track '1'"),
        ("unknown-wire-type", "unknown wire type 'CTA999'"),
    ],
)
def test_bad_inputs_are_refused_in_one_line_before_anything_is_written(
    simulated: Simulated, database: str, isolated_environment: Path, tmp_path: Path,
    case: str, expected: str,
) -> None:  # fmt: skip
    run, rig, masts = simulated.run, simulated.rig, simulated.masts
    extra: list[str] = []
    text = masts.read_text().splitlines()
    if case == "run-not-hdf5":
        run = write(tmp_path / "run.h5", b"not a run file")
    elif case == "rig-not-toml":
        rig = write(tmp_path / "rig.toml", "[cameras\n")
    elif case == "rig-missing":
        rig = tmp_path / "missing.toml"
    elif case == "register-bad-chainage":
        head, first, second, *rest = text
        second = ",".join(["x" if i == 3 else v for i, v in enumerate(second.split(","))])
        masts = write(tmp_path / "masts.csv", "\n".join([head, first, second, *rest]))
    elif case == "register-other-line":
        masts = write(tmp_path / "masts.csv", "\n".join(t.replace("demo-line", "L9") for t in text))
        extra = ["--line", "demo-line", "--track", "1"]
    else:
        extra = ["--wire-type", "CTA999"]
    result = invoke("process", run, "--rig", rig, "--masts", masts, "--db", database, *extra)
    assert expected in one_line_error(result)
    assert stored(database) == (0, 0)
    samples = isolated_environment / "samples"
    assert not samples.exists() or not any(samples.iterdir())


def test_a_failure_half_way_leaves_no_run_and_no_file(
    simulated: Simulated, database: str, isolated_environment: Path, monkeypatch
) -> None:
    from catenary_linescan.processor import stereo

    calls = []
    process_block = stereo.LineScanProcessor.process_staged  # in this process, any --workers

    def failing(self, block, staged):
        calls.append(block.first_scan)
        if len(calls) == 3:
            raise OSError(5, "Input/output error")
        return process_block(self, block, staged)

    monkeypatch.setattr(stereo.LineScanProcessor, "process_staged", failing)
    result = process(simulated, database)
    assert "Input/output error" in one_line_error(result)
    assert stored(database) == (0, 0)
    assert not any((isolated_environment / "samples").iterdir())


def test_the_processor_is_told_the_runs_wire_types_before_any_scan(
    simulated: Simulated, database: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    from catenary_linescan.processor import stereo

    told: list[list[str]] = []
    scans: list[int] = []
    process_block = stereo.LineScanProcessor.process_staged

    def expect_wire_types(self, wire_types):
        told.append([wire.name for wire in wire_types])
        raise UserError("told")  # stop here: the test needs no measurement

    def counting(self, block, staged):
        scans.append(block.first_scan)
        return process_block(self, block, staged)

    monkeypatch.setattr(stereo.LineScanProcessor, "expect_wire_types", expect_wire_types)
    monkeypatch.setattr(stereo.LineScanProcessor, "process_staged", counting)
    with simulated.masts.open(newline="") as f:
        registered = sorted({row["wire_type"] for row in csv.DictReader(f)})
    assert "told" in one_line_error(process(simulated, database))
    assert "told" in one_line_error(process(simulated, database, "--wire-type", "AC-150"))
    assert told == [registered, ["AC-150"]] and not scans
    assert stored(database) == (0, 0)


def test_an_unmigrated_database_is_refused(simulated: Simulated, tmp_path: Path) -> None:
    result = process(simulated, f"sqlite:///{tmp_path / 'new.sqlite'}")
    assert "catenary db upgrade" in one_line_error(result)


def test_export_gives_exactly_the_formats_columns(
    simulated: Simulated, database: str, tmp_path: Path
) -> None:
    assert process(simulated, database).exit_code == 0
    for what, columns in (("samples", EXPORT_COLUMNS), ("spans", SPAN_COLUMNS)):
        as_csv, as_parquet = tmp_path / f"{what}.csv", tmp_path / f"{what}.parquet"
        for reference, out in (("latest", as_csv), ("1", as_parquet)):
            result = invoke("export", reference, "--what", what, "-o", out, "--db", database)
            assert result.exit_code == 0, result.output
        table = pq.read_table(as_parquet)
        assert tuple(table.column_names) == columns
        with as_csv.open() as handle:
            rows = list(csv.reader(handle))
        assert tuple(rows[0]) == columns and len(rows) - 1 == table.num_rows > 0
    assert SPAN_COLUMNS == (
        "span", "mast_from", "mast_to", "start_chainage_m", "end_chainage_m", "wire",
        "wire_position", "wire_type", "min_residual_thickness_mm", "min_at_chainage_m",
        "mean_residual_thickness_mm", "height_min_mm", "height_max_mm", "stagger_min_mm",
        "stagger_max_mm", "samples",
    )  # fmt: skip
    bad = invoke("export", "7", "--what", "spans", "-o", tmp_path / "x.csv", "--db", database)
    assert "no run 7" in one_line_error(bad)
    bad = invoke("export", "1", "--what", "spans", "-o", tmp_path / "x.txt", "--db", database)
    assert "must be .csv, .xlsx, .parquet or .geojson" in one_line_error(bad)


@pytest.fixture(scope="module")
def repeated(simulated: Simulated, tmp_path_factory: pytest.TempPathFactory) -> Simulated:
    """A second run over the same section (the scene of seed 5): other motion, noise and
    encoder errors (-0.25 %, start 1.8 m off)."""
    folder = tmp_path_factory.mktemp("repeated")
    run = folder / "run.h5"
    errors = {"encoder_scale_error": -0.0025, "start_chainage_error_m": 1.8}
    record_run(run, {**SETTINGS, **errors, "seed": 6, "scene_seed": 5})
    return Simulated(
        run, run.with_suffix(".truth.h5"), run.with_suffix(".masts.csv"), simulated.rig
    )


def test_two_runs_over_the_same_wire_repeat_within_a_tenth_of_a_millimetre(
    simulated: Simulated, repeated: Simulated, database: str
) -> None:
    assert process(simulated, database).exit_code == 0
    assert process(repeated, database).exit_code == 0
    result = invoke("compare", "1", "2", "--db", database)
    assert result.exit_code == 0, result.output
    (within,) = [line for line in result.output.splitlines() if line.startswith("within")]
    share = float(within.split()[-2])
    assert share >= 95.0, result.output  # the paper: 90 %
    assert "histogram of B - A" in result.output
    bad = invoke("compare", "1", "9", "--db", database)
    assert "no run 9" in one_line_error(bad)


class _ThirdPartyProcessors:
    """A plugin whose processors fail: one when created, one that returns the wrong type."""

    @hookimpl
    def catenary_processors(self) -> list[Processor]:
        def broken(rig_path: Path, settings: Any) -> Any:
            raise RuntimeError("licence server unreachable")

        class Wrong:
            def process(self, block: Any) -> Any:
                return {"rows": 0}

            def finish(self) -> Any:
                return {"rows": 0}

        return [
            Processor("broken", "fails to start", broken),
            Processor("wrong", "returns a dict", lambda rig_path, settings: Wrong()),
        ]


@pytest.mark.parametrize(
    ("processor", "error"),
    [
        ("broken", "RuntimeError: licence server unreachable"),
        ("wrong", "TypeError: returned dict, not WireObservations"),
    ],
)
def test_a_failing_third_party_processor_is_named_in_one_line(
    simulated: Simulated,
    database: str,
    isolated_environment: Path,
    monkeypatch: pytest.MonkeyPatch,
    processor: str,
    error: str,
) -> None:
    def registry(**kwargs: Any) -> PluginRegistry:
        return PluginRegistry(plugins=[("acme", _ThirdPartyProcessors())], **kwargs)

    monkeypatch.setattr("catenary.plugins.manager.PluginRegistry", registry)
    result = process(simulated, database, "--processor", processor)
    expected = f"Error: processor {processor!r} of plugin 'acme' failed: {error}"
    assert one_line_error(result) == expected
    assert stored(database) == (0, 0)
    samples = isolated_environment / "samples"
    assert not samples.exists() or not any(samples.iterdir())


def test_scratch_files_of_dead_processes_are_removed_and_live_ones_kept(tmp_path: Path) -> None:
    host = socket.gethostname()
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    dead, live = int(gone.stdout), os.getpid()
    files = {
        "dead": tmp_path / f".pass1-{host}-{dead}-0123456789ab.parquet",
        "dead samples": tmp_path / f".samples-{host}-{dead}-0123456789ab.parquet",
        "live": tmp_path / f".pass1-{host}-{live}-ba9876543210.parquet",
        "other host": tmp_path / f".pass1-{host}-elsewhere-{dead}-0123456789ab.parquet",
        "legacy new": tmp_path / ".samples-0123456789ab.parquet",
        "legacy old": tmp_path / ".samples-ba9876543210.parquet",
        "a run's": tmp_path / "run-1-fedcba987654.parquet",
    }
    for path in files.values():
        path.write_bytes(b"")
    old = time.time() - LEGACY_SCRATCH_AGE_S - 10.0
    os.utime(files["legacy old"], (old, old))
    removed = remove_abandoned_scratch(tmp_path)
    expected = [files["dead"], files["dead samples"], files["legacy old"]]
    assert sorted(removed) == sorted(map(str, expected))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        files[k].name for k in ("live", "other host", "legacy new", "a run's")
    )


def test_a_process_killed_while_it_stored_leaves_an_object_the_next_one_resolves(
    engine: Engine, build: Any, tmp_path: Path
) -> None:
    """Killed after it put its samples file in the store, before or after the commit: the
    object is kept if its processing was committed, removed if not; another database's is
    left for that database's next process."""
    data = tmp_path / "data"
    folder = data / "samples"
    folder.mkdir(parents=True)
    store = open_store(Settings(database_url="sqlite://", data_dir=data))
    host = socket.gethostname()
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    ours = database_fingerprint(engine)
    theirs = "ffffffff" if ours != "ffffffff" else "00000000"
    source = tmp_path / "samples.parquet"
    source.write_bytes(b"PAR1")
    placed = {}
    for name, made, fingerprint in (("committed", "a", ours), ("not committed", "b", ours),
                                    ("another database's", "c", theirs)):  # fmt: skip
        processing = uuid.UUID(made * 32)
        key = samples_key("L/1", "1", "run", str(processing))
        store.put_file(source, key)
        store.put_bytes(b"PAR1", envelope_key(key))
        store.put_bytes(b"PNG", evidence_key(str(processing), 0, 0))
        hidden = (
            folder / f".samples-{host}-{int(gone.stdout)}-{processing.hex}{fingerprint}.parquet"
        )
        hidden.write_bytes(b"PAR1")
        placed[name] = (key, hidden)
    with session_scope(engine) as session:
        run = build.run(session, samples_key=placed["committed"][0])
        assert run.processing is not None
        run.processing.uuid = str(uuid.UUID("a" * 32))
    # without the database and the store: nothing to tell
    assert remove_abandoned_scratch(folder, engine=engine) == []
    removed = remove_abandoned_scratch(folder, engine=engine, store=store)
    not_committed = str(uuid.UUID("b" * 32))
    assert sorted(removed) == sorted(
        [
            str(placed["committed"][1]),
            *map(str, placed["not committed"]),
            envelope_key(placed["not committed"][0]),
            evidence_key(not_committed, 0, 0),
        ]
    )
    assert store.keys("evidence") == sorted(
        evidence_key(str(uuid.UUID(c * 32)), 0, 0) for c in "ac"
    )
    assert store.keys("samples") == sorted(
        [placed["committed"][0], placed["another database's"][0]]
    )
    assert store.keys("envelopes") == sorted(
        envelope_key(placed[name][0]) for name in ("committed", "another database's")
    )
    assert [p.name for p in folder.glob(".*")] == [placed["another database's"][1].name]


@pytest.mark.slow
def test_a_process_killed_mid_run_leaves_nothing_the_next_one_keeps(
    simulated: Simulated, database: str, isolated_environment: Path
) -> None:
    """``kill -9`` while pass 1 writes: no row, and the next ``process`` removes the hidden
    files the killed one left and stores the run."""
    main = "import sys; from catenary.cli import main; main(sys.argv[1:])"
    command = [sys.executable, "-c", main,
               "process", str(simulated.run), "--rig", str(simulated.rig),
               "--masts", str(simulated.masts), "--db", database]  # fmt: skip
    samples = isolated_environment / "samples"
    killed = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120.0
    while not list(samples.glob(".pass1-*")) and time.monotonic() < deadline:
        assert killed.poll() is None, "the process ended before it wrote its first pass"
        time.sleep(0.05)
    killed.kill()  # at once: on an idle machine pass 1 of this short run takes well under 1 s
    killed.wait()
    assert list(samples.glob(".pass1-*"))
    assert stored(database) == (0, 0)
    result = process(simulated, database)
    assert result.exit_code == 0, result.output
    assert stored(database)[0] == 1
    assert [p.name for p in samples.iterdir() if p.name.startswith(".")] == []


def test_ctrl_c_after_the_commit_says_the_run_is_stored_and_what_is_left(
    simulated: Simulated, database: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    def interrupted(*args: Any) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr("catenary.maintenance.alerts.evaluate_stored_run", interrupted)
    result = CliRunner().invoke(
        cli,
        ["process", str(simulated.run), "--rig", str(simulated.rig), "--masts",
         str(simulated.masts), "--db", database],
    )  # fmt: skip
    assert result.exit_code == 130, result.output
    with Session(create_engine(database)) as session:
        (run_id,) = session.scalars(select(Run.id)).all()
    assert result.output.strip().splitlines()[-1] == (
        f"interrupted: stored as run {run_id}, its alerts not evaluated "
        f"(catenary alerts evaluate --run {run_id})"
    )


def stationary(simulated: Simulated, folder: Path) -> Simulated:
    """The run as a vehicle that did not move records it: the encoder stays at 0."""
    run = folder / "stationary.h5"
    shutil.copyfile(simulated.run, run)
    with h5py.File(run, "r+") as f:
        f["/scans/position_m"][:] = 0.0
    return Simulated(run, simulated.truth, simulated.masts, simulated.rig)


def test_a_run_that_measured_no_wire_is_refused_and_nothing_stored(
    simulated: Simulated, database: str, isolated_environment: Path, tmp_path: Path
) -> None:
    """The stereo processor follows wires along the track: a vehicle that did not move gives
    it nothing to follow, and a run without one measured wire is not worth a row."""
    still = stationary(simulated, tmp_path)
    assert one_line_error(process(still, database, "--wire-type", "CTA120")) == (
        f"Error: run {still.run} covers 0.0 m: the vehicle did not move; no wire was measured "
        "in it: nothing stored"
    )
    assert stored(database) == (0, 0)
    assert not any((isolated_environment / "samples").iterdir())


class _Steady:
    """A processor that sees one wire in every scan, right above the roof's centre."""

    @hookimpl
    def catenary_processors(self) -> list[Processor]:
        class Steady:
            def process(self, block: Any) -> WireObservations:
                n = block.scans
                return WireObservations(
                    scan=block.first_scan + np.arange(n), wire=np.zeros(n, dtype=np.int64),
                    x_roof_mm=np.zeros(n), z_roof_mm=np.full(n, 1500.0),
                    wear_width_mm=np.full(n, 5.0), cameras=np.full(n, 3, dtype=np.int64),
                    reprojection_rms_px=np.full(n, 0.1),
                )  # fmt: skip

            def finish(self) -> WireObservations:
                return self.process(SimpleNamespace(scans=0, first_scan=0))

        return [Processor("steady", "one wire above the roof", lambda rig, settings: Steady())]


def test_a_stationary_run_that_measured_a_wire_is_stored_with_a_warning(
    simulated: Simulated, database: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Its samples are real (the wire at one chainage), but no span: say so on stderr."""

    def registry(**kwargs: Any) -> PluginRegistry:
        return PluginRegistry(plugins=[("acme", _Steady())], **kwargs)

    monkeypatch.setattr("catenary.plugins.manager.PluginRegistry", registry)
    still = stationary(simulated, tmp_path)
    result = invoke(
        "process", still.run, "--rig", still.rig, "--wire-type", "CTA120", "--db", database,
        "--processor", "steady",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "spans      0" in result.stdout
    assert result.stderr == (
        f"warning: run {still.run} covers 0.0 m: the vehicle did not move; no span measured\n"
    )
    assert stored(database) == (1, 0)


@pytest.mark.slow
def test_ctrl_c_as_the_run_commits_keeps_its_samples_file_and_says_it_is_stored(
    simulated: Simulated, database: str, isolated_environment: Path
) -> None:
    """SIGINT sent the moment the storing transaction commits (from SQLAlchemy's after-commit
    event, in this process): the run is stored, so its samples file stays, and the command
    says so with exit 130."""

    def interrupt_once_stored(session: Session) -> None:
        if any(isinstance(row, Run) for row in session.identity_map.values()):
            os.kill(os.getpid(), signal.SIGINT)

    event.listen(Session, "after_commit", interrupt_once_stored)
    try:
        result = process(simulated, database)
    finally:
        event.remove(Session, "after_commit", interrupt_once_stored)
    assert result.exit_code == 130, result.output
    with Session(create_engine(database)) as session:
        (run,) = session.scalars(select(Run)).all()
        key = run.processing.samples_key if run.processing else None
    assert result.output.strip().splitlines()[-1] == (
        f"interrupted: stored as run {run.id}, its alerts not evaluated "
        f"(catenary alerts evaluate --run {run.id})"
    )
    assert key is not None
    assert (isolated_environment / key).is_file()
    assert [p.name for p in (isolated_environment / "samples").rglob("*") if p.is_file()] == [
        Path(key).name
    ]


# -- runs that do not fit the rig, regions of interest, the recording state -----------------


@pytest.fixture(scope="module")
def cropped(simulated: Simulated) -> Simulated:
    """The same run recorded with every camera's lines cut to the sensor pixels its contact
    wires cross (150 px either side, from the truth's images of them; here they cross the
    sensor's right end), ``offset_px`` declared: 800-1,250 px cut at the left."""
    roi = {}
    with h5py.File(simulated.truth, "r") as f:
        seen = f["/wires/present"][:] & f["/wires/contact"][:]
        for name, camera in f["cameras"].items():
            u = camera["u_px"][:][seen]
            first = max(0, int(np.floor(np.nanmin(u))) - 150)
            stop = min(int(camera.attrs["pixels"]), int(np.ceil(np.nanmax(u))) + 151)
            roi[name] = (first, stop - first)
    assert all(offset > 500 and offset + width <= 4096 for offset, width in roi.values())
    run = simulated.run.with_name("cropped.h5")
    record_run(run, {**SETTINGS, **ENCODER_ERRORS}, roi=roi)
    return Simulated(run, simulated.truth, simulated.masts, simulated.rig)


def test_a_region_of_interest_processes_to_the_same_wear_as_the_whole_line(
    simulated: Simulated, cropped: Simulated, database: str, isolated_environment: Path
) -> None:
    truth = truth_of(simulated.truth)
    errors = []
    for run_id, run in enumerate((simulated, cropped), start=1):
        result = process(run, database)
        assert result.exit_code == 0, result.output
        on_wire, error = thickness_error(samples_of(database, isolated_environment, run_id), truth)
        assert np.mean(on_wire) > 0.999
        errors.append(error)
    whole, roi = errors
    assert roi.shape[0] >= 0.999 * whole.shape[0]  # the same samples: the wires lie in the ROI
    assert np.sqrt(np.nanmean(roi**2)) < 0.05
    assert np.nanmax(np.abs(roi)) < THICKNESS_TOLERANCE_MM
    assert abs(np.sqrt(np.nanmean(roi**2)) - np.sqrt(np.nanmean(whole**2))) < 0.005


@pytest.fixture(scope="module")
def short_run(simulated: Simulated) -> Path:
    """20 m of straight line without an overlap: a run quick to process."""
    run = simulated.run.with_name("short.h5")
    record_run(run, {"length_m": 20.0, "overlap": False, "speed_kmh": 160.0, "seed": 8})
    return run


def edited(run: Path, folder: Path, edit: Any) -> Path:
    """A copy of ``run`` in ``folder`` changed by ``edit(h5py.File)``."""
    copy = folder / "edited.h5"
    shutil.copyfile(run, copy)
    with h5py.File(copy, "r+") as f:
        edit(f)
    return copy


def process_short(run: Path, simulated: Simulated, database: str) -> Result:
    return invoke("process", run, "--rig", simulated.rig, "--wire-type", "CTA120", "--db", database)


def test_a_run_cut_to_half_the_sensor_is_refused_naming_the_camera(
    simulated: Simulated, database: str, isolated_environment: Path, tmp_path: Path
) -> None:
    run = tmp_path / "cut.h5"
    record_run(
        run,
        {"length_m": 5.0, "overlap": False, "seed": 8},
        roi={name: (0, 2048) for name in ("cam1", "cam2", "cam3", "cam4")},
    )
    with h5py.File(run, "r+") as f:  # cut without saying so: no offset_px
        for camera in f["cameras"].values():
            del camera.attrs["offset_px"]
    assert one_line_error(process_short(run, simulated, database)) == (
        f"Error: {run}: camera 'cam1': lines of 2048 pixels, but rig 'demo-rig' calibrated it "
        "with 4096 (a region of interest declares offset_px)"
    )
    assert stored(database) == (0, 0)
    samples = isolated_environment / "samples"
    assert not samples.exists() or not any(samples.iterdir())


def test_a_bit_depth_above_the_lines_type_is_refused_naming_the_camera(
    simulated: Simulated, short_run: Path, database: str, tmp_path: Path
) -> None:
    run = edited(
        short_run, tmp_path, lambda f: f["cameras/cam3/lines"].attrs.__setitem__("bit_depth", 12)
    )
    line = one_line_error(process_short(run, simulated, database))
    for needle in (str(run), "camera 'cam3'", "bit_depth = 12", "8 bits", "uint8"):
        assert needle in line, (needle, line)
    assert stored(database) == (0, 0)


def test_an_overview_camera_is_named_once_and_ignored(
    simulated: Simulated,
    short_run: Path,
    database: str,
    isolated_environment: Path,
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:
    def overview(f: h5py.File) -> None:
        n = f["scans/position_m"].shape[0]
        f["cameras/overview/lines"] = np.zeros((n, 1280), np.uint8)
        f["cameras/overview/lines"].attrs["bit_depth"] = 8

    plain = process_short(short_run, simulated, database)
    assert plain.exit_code == 0, plain.output
    assert not caplog.records
    result = process_short(edited(short_run, tmp_path, overview), simulated, database)
    assert result.exit_code == 0, result.output
    assert [r.getMessage() for r in caplog.records] == [
        "warning: camera 'overview' of the run is not in rig 'demo-rig': ignored"
    ]
    one = samples_of(database, isolated_environment, 1)
    two = samples_of(database, isolated_environment, 2)
    assert one["scan"].shape[0] > 100
    np.testing.assert_array_equal(one["residual_thickness_mm"], two["residual_thickness_mm"])


def _interrupted(f: h5py.File) -> None:
    for name in ("completed_scans", "completed_at"):
        del f.attrs[name]
    f.attrs["complete"] = False


def _another_recorder(f: h5py.File) -> None:
    for name in ("complete", "completed_scans", "completed_at"):
        del f.attrs[name]


@pytest.mark.parametrize(("edit", "warned"), [(_interrupted, 1), (_another_recorder, 0)])
def test_the_recording_state_warns_once_when_interrupted_and_never_when_unknown(
    simulated: Simulated, short_run: Path, database: str, tmp_path: Path, edit: Any, warned: int
) -> None:
    run = edited(short_run, tmp_path, edit)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = process_short(run, simulated, database)
    assert result.exit_code == 0, result.output
    state = [w for w in caught if issubclass(w.category, RunFileWarning)]
    assert len(state) == warned, [str(w.message) for w in state]
