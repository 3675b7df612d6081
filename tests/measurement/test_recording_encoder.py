"""The recorder with the wheel encoder: positions of free-running scans interpolated from its
readings (written to ``/encoder/*``), the check of encoder-triggered scans against it, one
clock, and invalid lines."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from catenary.cli import cli
from catenary.domain import CameraLines, EncoderReadings, RunHeader, ScanBlock, VehicleSamples
from catenary.errors import UserError
from catenary.measurement.recording import ENCODER_WAIT_S, record_run
from catenary.measurement.runfile import open_run
from catenary.plugins import PluginRegistry, hookimpl
from catenary.plugins.types import Source

RATE_HZ = 100.0
PIXELS = 8
ENCODER_HZ = 200.0


def accelerating(t: np.ndarray) -> np.ndarray:
    """The encoder's count [m] at ``t``: from 10 m/s at 2 m/s², its own origin at 5 m."""
    return 5.0 + 10.0 * t + t**2


class Scans:
    """``blocks`` blocks of scans at 100 Hz. Free-running (``positions`` None): NaN positions
    and ``positions_from_encoder``; else positions ``positions(time_s)``. Camera ``c``'s lines
    ``invalid`` (scan indices) are zeros, marked invalid."""

    def __init__(
        self,
        blocks: int,
        positions: Callable[[np.ndarray], np.ndarray] | None = None,
        invalid: tuple[int, ...] = (),
        clock_zero_unix_s: float | None = None,
    ) -> None:
        self.count = blocks
        self.own = positions
        self.positions_from_encoder = positions is None
        self.invalid = np.asarray(invalid, dtype=np.int64)
        self.zero = clock_zero_unix_s
        self.clock_zero_unix_s: float | None = None  # known once the first block is out
        self.header = RunHeader(
            line="L1",
            track="1",
            vehicle="car",
            direction="increasing",
            start_chainage_m=0.0,
            started_at="2024-05-01T10:00:00.000Z",
            scan_rate_hz=RATE_HZ,
            scans=0,
            camera_pixels={"c": PIXELS},
            camera_bit_depth={"c": 8},
            camera_offset_px={"c": 100},
        )

    def blocks(self, block_scans: int) -> Iterator[ScanBlock]:
        for k in range(self.count):
            index = np.arange(k * block_scans, (k + 1) * block_scans)
            time_s = index / RATE_HZ
            lines = np.full((block_scans, PIXELS), 7, dtype=np.uint8)
            valid = ~np.isin(index, self.invalid)
            lines[~valid] = 0
            self.clock_zero_unix_s = self.zero
            yield ScanBlock(
                first_scan=int(index[0]),
                position_m=np.full(block_scans, np.nan) if self.own is None else self.own(time_s),
                time_s=time_s,
                cameras={"c": CameraLines(lines, 8, 100, valid if self.invalid.size else None)},
                vehicle=VehicleSamples(time_s, *np.zeros((3, block_scans))),
            )

    def close(self) -> None:
        pass


class Vehicle:
    """Samples and encoder readings at 200 Hz from -0.1 s, ``motion`` the encoder's count,
    given up to ``lag_s`` before the time asked for (a live bus that lags) unless ``final``.
    Notes every call in ``calls``."""

    def __init__(self, motion: Callable[[np.ndarray], np.ndarray], lag_s: float = 0.0) -> None:
        self.motion = motion
        self.lag_s = lag_s
        self.next = {"vehicle": -20, "encoder": -20}
        self.calls: list[str] = []
        self.given: list[EncoderReadings] = []

    def _times(self, kind: str, until_s: float, final: bool) -> np.ndarray:
        self.calls.append(kind)
        stop = int(np.floor((until_s - (0.0 if final else self.lag_s)) * ENCODER_HZ)) + 1
        index = np.arange(self.next[kind], stop)
        self.next[kind] = max(self.next[kind], stop)
        return index / ENCODER_HZ

    def vehicle_samples(self, until_s: float, *, final: bool = False) -> Iterator[VehicleSamples]:
        t = self._times("vehicle", until_s, final)
        if t.shape[0]:
            yield VehicleSamples(t, *np.zeros((3, t.shape[0])))

    def encoder_readings(self, until_s: float, *, final: bool = False) -> Iterator[EncoderReadings]:
        t = self._times("encoder", until_s, final)
        for part in np.array_split(t, 3):  # several parts per call
            if part.shape[0]:
                readings = EncoderReadings(part, self.motion(part))
                self.given.append(readings)
                yield readings

    def align_clock(self, clock_zero_unix_s: float) -> None:
        self.calls.append(f"align {clock_zero_unix_s}")

    def close(self) -> None:
        pass


class SensorsOnly:
    """A vehicle source without the encoder."""

    def vehicle_samples(self, until_s: float, *, final: bool = False) -> Iterator[VehicleSamples]:
        return iter(())

    def close(self) -> None:
        pass


def scans_of(path: Path) -> tuple[np.ndarray, np.ndarray]:
    with open_run(path) as run:
        blocks = list(run.blocks(1000))
        assert run.header.camera_offset_px == {"c": 100}
    return (
        np.concatenate([b.time_s for b in blocks]),
        np.concatenate([b.position_m for b in blocks]),
    )


def test_free_running_scans_take_their_positions_from_the_encoder(tmp_path: Path) -> None:
    out = tmp_path / "run.h5"
    vehicle = Vehicle(accelerating)
    result = record_run(out, Scans(12), vehicle=vehicle, block_scans=25)
    time_s, position_m = scans_of(out)
    assert time_s.shape == (300,)
    truth = accelerating(time_s) - accelerating(time_s[:1])
    # linear between readings 5 ms apart: off by at most (5 ms)² / 8 * 2 m/s²
    np.testing.assert_allclose(position_m, truth, atol=1e-5, rtol=0)
    assert position_m[0] == 0.0 and np.all(np.diff(position_m) > 0)
    given_t = np.concatenate([r.time_s for r in vehicle.given])
    given_p = np.concatenate([r.position_m for r in vehicle.given])
    with h5py.File(out) as f:  # the raw readings, as given
        np.testing.assert_array_equal(f["encoder/time_s"][:], given_t)
        np.testing.assert_array_equal(f["encoder/position_m"][:], given_p)
    assert given_t[-1] >= time_s[-1] + 0.5  # up to the last scan + VEHICLE_MARGIN_S
    assert result.encoder_readings == given_t.shape[0] and result.scans_off_encoder == 0
    assert result.details() == [f"positions from {given_t.shape[0]} encoder readings"]


@pytest.mark.parametrize("lag_s", [0.3, ENCODER_WAIT_S - 0.5])
def test_blocks_wait_for_a_lagging_encoder(tmp_path: Path, lag_s: float) -> None:
    out = tmp_path / "run.h5"
    result = record_run(out, Scans(40), vehicle=Vehicle(accelerating, lag_s), block_scans=10)
    time_s, position_m = scans_of(out)
    assert result.scans == 400 and result.scans_off_encoder == 0
    np.testing.assert_allclose(
        position_m, accelerating(time_s) - accelerating(time_s[:1]), atol=1e-5, rtol=0
    )


def test_scans_the_encoder_never_reaches_hold_their_position(tmp_path: Path) -> None:
    """An encoder that lags more than ENCODER_WAIT_S: the blocks are written with the
    positions known (the last reading's after it), counted, and never decrease."""
    out = tmp_path / "run.h5"
    lag_s = ENCODER_WAIT_S + 1.0
    result = record_run(out, Scans(40), vehicle=Vehicle(accelerating, lag_s), block_scans=10)
    _, position_m = scans_of(out)
    assert result.scans == 400
    assert 0 < result.scans_off_encoder < 400
    assert np.all(np.diff(position_m) >= 0)
    assert f"{result.scans_off_encoder} scans outside the encoder's readings" in "; ".join(
        result.details()
    )


def test_free_running_scans_without_an_encoder_are_refused_before_recording(
    tmp_path: Path,
) -> None:
    out = tmp_path / "run.h5"
    with pytest.raises(UserError, match=r"^source 'x' takes its scans' positions from the wheel"):
        record_run(out, Scans(2), block_scans=10, scan_source="source 'x'")
    with pytest.raises(UserError, match=r"\(--vehicle-source can\), which source 'y' does not$"):
        record_run(
            out,
            Scans(2),
            vehicle=SensorsOnly(),
            block_scans=10,
            scan_source="source 'x'",
            vehicle_source="source 'y'",
        )
    assert not out.exists()


def test_encoder_triggered_scans_are_checked_against_the_encoder(tmp_path: Path) -> None:
    """Lines every 0.1 m at 10 m/s; the CAN encoder reads 0.1 % short."""
    out = tmp_path / "run.h5"

    def encoder(t: np.ndarray) -> np.ndarray:
        return 3.0 + 10.0 * 0.999 * t

    scans = Scans(10, positions=lambda t: 10.0 * t)
    result = record_run(out, scans, vehicle=Vehicle(encoder), block_scans=100)
    assert result.lines_distance_m == pytest.approx(99.9)
    assert result.encoder_distance_m == pytest.approx(99.9 * 0.999)
    assert result.details() == ["encoder check: lines give 99.9 m, CAN encoder 99.8 m (+0.10 %)"]
    with h5py.File(out) as f:
        assert "encoder" not in f  # the lines are triggered by the encoder itself
    _, position_m = scans_of(out)
    np.testing.assert_array_equal(position_m, 10.0 * (np.arange(1000) / RATE_HZ))  # its own


def test_the_encoder_check_waits_for_readings_after_the_last_scans(tmp_path: Path) -> None:
    """A lagging bus: the last scans are covered only by the final readings."""
    out = tmp_path / "run.h5"
    scans = Scans(10, positions=lambda t: 10.0 * t)
    result = record_run(out, scans, vehicle=Vehicle(lambda t: 10.0 * t, 1.0), block_scans=100)
    assert result.lines_distance_m == pytest.approx(99.9)
    assert result.encoder_distance_m == pytest.approx(99.9)


def test_one_clock_the_scan_sources_zero_goes_to_the_vehicle_stream(tmp_path: Path) -> None:
    vehicle = Vehicle(accelerating)
    zero = 1_700_000_000.25
    record_run(
        tmp_path / "run.h5", Scans(3, clock_zero_unix_s=zero), vehicle=vehicle, block_scans=10
    )
    assert vehicle.calls[0] == f"align {zero}"  # before any sample is asked for
    assert vehicle.calls.count(f"align {zero}") == 1
    vehicle = Vehicle(accelerating)
    record_run(tmp_path / "other.h5", Scans(3), vehicle=vehicle, block_scans=10)
    assert not any(call.startswith("align") for call in vehicle.calls)  # no zero: not called


def test_invalid_lines_are_written_and_counted(tmp_path: Path) -> None:
    out = tmp_path / "run.h5"
    scans = Scans(3, positions=lambda t: t, invalid=(12, 13, 29))
    result = record_run(out, scans, block_scans=10)
    assert result.invalid_lines == {"c": 3}
    assert result.details()[0] == "3 lines invalid (c 3)"
    with open_run(out) as run:
        (block,) = run.blocks(30)
    valid = block.cameras["c"].valid
    assert valid is not None
    np.testing.assert_array_equal(np.flatnonzero(~valid), [12, 13, 29])


class CameraPlugin:
    @hookimpl
    def catenary_sources(self) -> list[Source]:
        def free(settings: Mapping[str, Any]) -> Scans:
            return Scans(2)

        def lossy(settings: Mapping[str, Any]) -> Scans:
            return Scans(3, positions=lambda t: t, invalid=(12, 13, 29))

        return [Source("free-scans", "free-running", free), Source("lossy", "lossy", lossy)]


def test_the_command_says_it_in_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def registry(**kwargs: Any) -> PluginRegistry:
        return PluginRegistry(plugins=[("camera-test", CameraPlugin())], **kwargs)

    monkeypatch.setattr("catenary.plugins.manager.PluginRegistry", registry)
    out = tmp_path / "run.h5"
    result = CliRunner().invoke(cli, ["record", str(out), "--source", "free-scans"])
    assert result.exit_code == 1 and not out.exists()
    assert result.output == (
        "Error: source 'free-scans' of plugin 'camera-test' takes its scans' positions from the "
        "wheel encoder: it needs a vehicle source that reads the encoder (--vehicle-source "
        "can)\n"
    )
    args = ["record", str(out), "--source", "lossy", "--block-scans", "10"]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert result.stdout == (
        f"recorded {out}: 30 scans, 30 vehicle samples (0 flagged); 3 lines invalid (c 3)\n"
    )
