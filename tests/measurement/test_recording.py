"""``catenary record``: scan source + vehicle sensor source into a run file; Ctrl-C; errors."""

from __future__ import annotations

import os
import signal
import warnings
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
from click.testing import CliRunner, Result

from catenary.cli import cli
from catenary.cli.record import parse_options
from catenary.domain import CameraLines, RunHeader, ScanBlock, VehicleSamples
from catenary.errors import UserError
from catenary.measurement.recording import record_run
from catenary.measurement.runfile import RunFileWarning, open_run
from catenary.plugins import PluginRegistry, hookimpl
from catenary.plugins.types import Source, VehicleSource
from catenary_can.decode import DEFAULT_METRES_PER_PULSE
from catenary_can.reader import load_database, open_log

# -- fakes: a scan source and a vehicle sensor source that misbehave on request ---------------

SCAN_RATE_HZ = 100.0
PIXELS = 16


def fake_header(scans: int) -> RunHeader:
    return RunHeader(
        line="L1",
        track="1",
        vehicle="test-car",
        direction="increasing",
        start_chainage_m=100.0,
        started_at="2024-05-01T10:00:00.000Z",
        scan_rate_hz=SCAN_RATE_HZ,
        scans=scans,
        camera_pixels={"c": PIXELS},
        camera_bit_depth={"c": 8},
    )


def fake_block(first: int, n: int) -> ScanBlock:
    index = np.arange(first, first + n)
    time_s = index / SCAN_RATE_HZ
    lines = (index[:, None] + np.arange(PIXELS)[None, :]).astype(np.uint8)
    return ScanBlock(
        first_scan=first,
        position_m=index * 0.1,
        time_s=time_s,
        cameras={"c": CameraLines(lines, 8)},
        vehicle=VehicleSamples(time_s, np.full(n, 1.0), np.full(n, 2.0), np.full(n, 3.0)),
    )


class FakeScans:
    """Settings: ``blocks`` given (10), then ``then``: "end", "keyboard-interrupt" (raised by
    the source), "sigint" (a real SIGINT while the source is waited on) or "error"."""

    def __init__(self, settings: Mapping[str, Any]) -> None:
        self.count = int(settings.get("blocks", 10))
        self.then = str(settings.get("then", "end"))
        self.header = fake_header(0)  # length unknown, like a live camera
        self.closed = False

    def blocks(self, block_scans: int) -> Iterator[ScanBlock]:
        for k in range(self.count):
            yield fake_block(k * block_scans, block_scans)
        if self.then == "keyboard-interrupt":
            raise KeyboardInterrupt
        if self.then == "sigint":
            os.kill(os.getpid(), signal.SIGINT)
            yield fake_block(self.count * block_scans, block_scans)  # never reached
        if self.then == "error":
            raise RuntimeError("camera link lost")

    def close(self) -> None:
        self.closed = True


class FakeVehicle:
    """200 Hz samples on demand; ``faults`` (sample indices) flagged; ``sigint_on_call`` sends
    SIGINT while the recorder is writing that call's samples."""

    def __init__(self, settings: Mapping[str, Any]) -> None:
        self.faults = set(settings.get("faults", []))
        self.sigint_on_call = settings.get("sigint_on_call")
        self.next = -20  # samples from -0.1 s
        self.calls = 0

    def vehicle_samples(self, until_s: float, *, final: bool = False) -> Iterator[VehicleSamples]:
        self.calls += 1
        if self.calls == self.sigint_on_call:
            os.kill(os.getpid(), signal.SIGINT)
        stop = int(np.floor(until_s * 200.0)) + 1
        for first in range(self.next, stop, 7):  # odd blocks, to cross the held sample
            index = np.arange(first, min(first + 7, stop))
            t = index / 200.0
            fault = np.isin(index, sorted(self.faults))
            yield VehicleSamples(t, index * 0.01, -index * 0.01, np.zeros(t.shape), fault)
        self.next = max(self.next, stop)

    def close(self) -> None:
        pass


class FakePlugin:
    @hookimpl
    def catenary_sources(self) -> list[Source]:
        def broken(settings: Mapping[str, Any]) -> Any:
            raise ZeroDivisionError("division by zero")

        return [
            Source("fake-scans", "test scans", FakeScans),
            Source("fake-broken", "fails to open", broken),
        ]

    @hookimpl
    def catenary_vehicle_sources(self) -> list[VehicleSource]:
        return [VehicleSource("fake-vehicle", "test vehicle sensors", FakeVehicle)]


@pytest.fixture(autouse=True)
def fake_plugin(monkeypatch: pytest.MonkeyPatch) -> None:
    def registry(**kwargs: Any) -> PluginRegistry:
        return PluginRegistry(plugins=[("fake", FakePlugin())], **kwargs)

    monkeypatch.setattr("catenary.plugins.manager.PluginRegistry", registry)


def record(*args: str) -> Result:
    return CliRunner().invoke(cli, ["record", *map(str, args)])


def read_run(path: Path) -> tuple[Any, np.ndarray, np.ndarray]:
    """The run's header, scan times and vehicle faults (reading must not warn)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RunFileWarning)
        with open_run(path) as run:
            blocks = list(run.blocks(100))
            complete = run.complete
            header = run.header
    assert complete
    time_s = np.concatenate([b.time_s for b in blocks])
    fault = np.concatenate([b.vehicle.fault for b in blocks])
    return header, time_s, fault


# -- pure parts --------------------------------------------------------------------------------


def test_parse_options_reads_toml_values_else_strings() -> None:
    options = parse_options(
        ["length_m=20", "x=1.5", "ok=true", "name=can0", "path=/a/b.blf", "t={a = 1}", "s='1'"],
        "--source-option",
    )
    assert options == {
        "length_m": 20,
        "x": 1.5,
        "ok": True,
        "name": "can0",
        "path": "/a/b.blf",
        "t": {"a": 1},
        "s": "1",
    }


def test_flagged_vehicle_samples_are_written_as_nan(tmp_path: Path) -> None:
    out = tmp_path / "run.h5"
    vehicle = FakeVehicle({"faults": [5, 13, 14, 40]})  # 13, 14 straddle a block of 7
    result = record_run(out, FakeScans({"blocks": 3}), vehicle=vehicle, block_scans=10)
    assert result.scans == 30 and result.flagged_vehicle_samples == 4
    import h5py

    with h5py.File(out) as f:
        t = f["vehicle/time_s"][:]
        left = f["vehicle/left_mm"][:]
    index = np.rint(t * 200.0).astype(int)
    assert index.tolist() == list(range(-20, index[-1] + 1))
    nan = set(index[np.isnan(left)].tolist())
    assert nan == {5, 13, 14, 40}


# -- the command: simulator and a CAN log -----------------------------------------------------

DB = load_database()
DISP = DB.get_message_by_name("DisplacementSensors")
ENC = DB.get_message_by_name("WheelEncoder")
T0 = 1_700_000_000.0
PERIOD_S = 0.005


def can_log(path: Path, start_s: float, stop_s: float) -> Path:
    """A BLF log from ``start_s`` to ``stop_s`` (scan clock: T0 is scan time 0) with faults:
    a dropped frame at 0.3 s, the right sensor stuck 0.5-1.0 s, lateral out of range at
    0.2 s, the module fault bit at 1.1 s."""
    rng = np.random.default_rng(3)
    first = round(start_s / PERIOD_S)
    with can.Logger(path) as logger:
        for i in range(first, round(stop_s / PERIOD_S)):
            t = i * PERIOD_S
            pulses = round(16.0 * (t - start_s) / DEFAULT_METRES_PER_PULSE)
            enc = ENC.encode({"pulse_count": pulses, "status": 0, "counter": i % 16})
            logger.on_message_received(
                can.Message(timestamp=T0 + t, arbitration_id=0x100, is_extended_id=False, data=enc)
            )
            if i == round(0.3 / PERIOD_S):
                continue
            signals = {
                "left_mm": round(3.0 + rng.normal(0.0, 0.5), 2),
                "right_mm": -7.77 if 0.5 <= t <= 1.0 else round(-2.0 + rng.normal(0.0, 0.5), 2),
                "lateral_mm": 222.0 if i == round(0.2 / PERIOD_S) else round(rng.normal(), 2),
                "status": 0b1000 if i == round(1.1 / PERIOD_S) else 0,
                "counter": i % 16,
            }
            data = DISP.encode(signals, strict=False)
            logger.on_message_received(
                can.Message(timestamp=T0 + t, arbitration_id=0x110, is_extended_id=False, data=data)
            )
    return path


@pytest.mark.slow
def test_record_the_simulator_with_a_can_log_as_vehicle_source(
    tmp_path: Path, small_rig_file: Path
) -> None:
    rig = small_rig_file
    log = can_log(tmp_path / "sensors.blf", -0.2, 2.0)
    out = tmp_path / "run.h5"
    result = record(
        out,
        "--source", "simulator",
        "--source-option", f"rig={rig}",
        "--source-option", "length_m=20",
        "--source-option", "scan_rate_hz=250",
        "--vehicle-source", "can",
        "--vehicle-option", f"log={log}",
        "--vehicle-option", f"time_zero_s={T0}",
        "--block-scans", "64",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "recorded" in result.stdout and "CAN log" in result.stdout
    header, scan_t, flagged = read_run(out)
    assert header.vehicle == "demo-rig" and header.camera_pixels["cam1"] == 512
    assert scan_t.shape[0] == header.scans > 250

    # The faulty samples as the CAN source sees them, and the stretches they affect.
    with open_log(log, time_zero_s=T0) as stream:
        samples = list(stream.vehicle_samples(np.inf))
    t = np.concatenate([s.time_s for s in samples])
    bad_t = t[np.concatenate([s.fault for s in samples])]
    distance = np.abs(scan_t[:, None] - bad_t[None, :]).min(axis=1)
    must = distance < PERIOD_S - 1e-9  # interpolated from a faulty sample
    may = distance < 2 * PERIOD_S + 1e-9  # within one more sample (the neighbours written NaN)
    assert must.any()
    assert not (must & ~flagged).any(), scan_t[must & ~flagged]
    assert not (flagged & ~may).any(), scan_t[flagged & ~may]
    stuck = (scan_t >= 0.5) & (scan_t <= 1.0)
    assert flagged[stuck].all()
    assert flagged.sum() < 0.6 * flagged.shape[0]


@pytest.mark.slow
def test_record_the_simulator_alone_uses_its_own_sensor_samples(
    tmp_path: Path, small_rig_file: Path
) -> None:
    out = tmp_path / "run.h5"
    rig = small_rig_file
    result = record(
        out, "--source", "simulator", "--source-option", f"rig={rig}",
        "--source-option", "length_m=6", "--source-option", "scan_rate_hz=200",
        "--max-scans", "50",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert (
        "recorded" in result.stdout and "50 scans, 50 vehicle samples (0 flagged)" in result.stdout
    )
    header, _, flagged = read_run(out)
    assert header.scans == 50 and not flagged.any()


# -- Ctrl-C ----------------------------------------------------------------------------------


def check_kept(out: Path, scans: int) -> None:
    header, time_s, _ = read_run(out)  # complete: the marker is there, nothing warns
    assert header.scans == scans
    np.testing.assert_allclose(time_s, np.arange(scans) / SCAN_RATE_HZ)


@pytest.mark.parametrize("how", ["keyboard-interrupt", "sigint"])
def test_ctrl_c_while_waiting_keeps_the_blocks_before_it(tmp_path: Path, how: str) -> None:
    out = tmp_path / "run.h5"
    before = signal.getsignal(signal.SIGINT)  # Python's default, or SIG_IGN under nohup or &
    result = record(
        out, "--source", "fake-scans", "--source-option", "blocks=3",
        "--source-option", f"then={how}", "--block-scans", "10",
    )  # fmt: skip
    assert result.exit_code == 130, result.output
    assert result.stderr.strip().splitlines()[-1] == (
        f"interrupted: kept 30 scans in {out} (complete up to the last block)"
    )
    assert "Traceback" not in result.output
    check_kept(out, 30)
    assert signal.getsignal(signal.SIGINT) is before  # restored


def test_ctrl_c_while_writing_finishes_the_block_then_stops(tmp_path: Path) -> None:
    out = tmp_path / "run.h5"
    result = record(
        out, "--source", "fake-scans", "--block-scans", "10",
        "--vehicle-source", "fake-vehicle", "--vehicle-option", "sigint_on_call=4",
    )  # fmt: skip
    assert result.exit_code == 130, result.output
    assert "interrupted: kept 40 scans" in result.stderr
    check_kept(out, 40)


# -- errors ----------------------------------------------------------------------------------


def test_a_source_failing_midway_keeps_the_scans_marked_incomplete(tmp_path: Path) -> None:
    out = tmp_path / "run.h5"
    result = record(
        out, "--source", "fake-scans", "--source-option", "blocks=2",
        "--source-option", "then=error", "--block-scans", "10",
    )  # fmt: skip
    assert result.exit_code == 1
    lines = result.output.strip().splitlines()
    assert lines[-1] == (
        "Error: source 'fake-scans' of plugin 'fake' failed: RuntimeError: camera link lost; "
        "kept 20 scans in "
        f"{out} (marked complete = false: reads as interrupted)"
    )
    with pytest.warns(RunFileWarning) as warned, open_run(out) as run:
        assert run.header.scans == 20 and run.complete is False
    assert len(warned) == 1


def test_a_source_failing_before_any_scan_leaves_no_file(tmp_path: Path) -> None:
    out = tmp_path / "run.h5"
    result = record(
        out,
        "--source",
        "fake-scans",
        "--source-option",
        "blocks=0",
        "--source-option",
        "then=error",
    )
    assert result.exit_code == 1
    assert "camera link lost" in result.output and not out.exists()
    result = record(out, "--source", "fake-scans", "--source-option", "blocks=0")
    assert result.exit_code == 1 and not out.exists()
    assert "source 'fake-scans' of plugin 'fake' gave no scans: nothing recorded" in result.output
    result = record(
        out,
        "--source",
        "fake-scans",
        "--source-option",
        "blocks=0",
        "--source-option",
        "then=sigint",
    )
    assert result.exit_code == 130 and not out.exists()
    assert "interrupted before the first block: nothing recorded" in result.output
    result = record(out, "--source", "fake-broken")
    assert result.exit_code == 1
    assert result.output.strip() == (
        "Error: source 'fake-broken' of plugin 'fake' failed: ZeroDivisionError: division by zero"
    )


def test_sources_in_the_wrong_role_and_unknown_names_are_one_line(tmp_path: Path) -> None:
    out = tmp_path / "run.h5"
    cases = [
        (["--source", "fake-vehicle"], "unknown source 'fake-vehicle' (known: "),
        (["--source", "fake-vehicle"], "'fake-vehicle' is a vehicle source: use --vehicle-source"),
        (["--source", "fake-scans", "--vehicle-source", "fake-scans"],
         "'fake-scans' is a source: use --source"),
        (["--source", "nope"], "unknown source 'nope' (known: "),
        (["--source", "fake-scans", "--vehicle-source", "can", "--vehicle-option", "log=no.blf"],
         "no.blf: no such CAN log file"),
    ]  # fmt: skip
    for args, message in cases:
        result = record(out, *args)
        assert result.exit_code == 1, result.output
        assert message in result.output
        assert len(result.output.strip().splitlines()) == 1, result.output
        assert not out.exists()


def test_usage_errors(tmp_path: Path) -> None:
    out = tmp_path / "run.h5"
    assert record(out).exit_code == 2  # no source
    assert record(out, "--source", "fake-scans", "--source-option", "oops").exit_code == 2
    assert record(out, "--source", "fake-scans", "--vehicle-option", "a=1").exit_code == 2
    out.write_text("x")
    result = record(out, "--source", "fake-scans")
    assert result.exit_code == 1 and "already exists" in result.output
    assert record(out, "--source", "fake-scans", "--overwrite").exit_code == 0


def test_config_record_section(tmp_path: Path) -> None:
    config = tmp_path / "config.toml"
    config.write_text(
        '[record]\nsource = "fake-scans"\nmax_scans = 25\nblock_scans = 10\n'
        "[record.source_options]\nblocks = 5\n"
    )
    out = tmp_path / "run.h5"
    result = CliRunner().invoke(cli, ["--config", str(config), "record", str(out)])
    assert result.exit_code == 0, result.output
    check_kept(out, 25)
    config.write_text('[record]\nsorce = "fake-scans"\n')
    result = CliRunner().invoke(cli, ["--config", str(config), "record", str(out)])
    assert result.exit_code == 1 and "unknown key record.sorce" in result.output


def test_vehicle_stream_protocol_matches_the_can_stream(tmp_path: Path) -> None:
    log = can_log(tmp_path / "s.blf", 0.0, 0.1)
    with open_log(log) as stream:
        assert callable(stream.vehicle_samples)
    with pytest.raises(UserError, match="already exists"):
        record_run(log, FakeScans({}))
