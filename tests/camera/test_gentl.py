"""The GenTL backend against a real GenTL producer: genicam's simulated ``viky.cti`` (three
devices ``VikyTL_DEV_red``/``green``/``blue``, serials 0-2; a black 20 x 20 ball on white that
moves one pixel right per frame; no timestamps, no exposure time)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import genicam
import numpy as np
import pytest
from click.testing import CliRunner

from catenary.cli import cli
from catenary.domain import CameraLines
from catenary.errors import UserError
from catenary.measurement.runfile import open_run
from catenary_camera import gentl
from catenary_camera.backend import CameraUnavailable
from catenary_camera.gentl import GenTLCamera
from catenary_camera.settings import parse_settings
from catenary_camera.stream import open_gige
from tests.camera.canlog import can_log

VIKY = Path(genicam.__file__).parent / "viky.cti"
NAMES = ("red", "green", "blue")
WIDTH = 256
LINES = 100  # lines per frame (viky's least Height)
RATE_HZ = 300.0  # lines per second: 3 frames per second (a resync needs an 83 ms delay)
BALL = 20  # the ball's rows (and columns)


def settings(**extra: Any) -> dict[str, Any]:
    return {
        "backend": "gentl",
        "cti": str(VIKY),
        "line_rate_hz": RATE_HZ,
        "lines_per_frame": LINES,
        "timeout_s": 5.0,
        "cameras": {name: {"device_id": f"VikyTL_DEV_{name}", "width": WIDTH} for name in NAMES},
        **extra,
    }


def valid_lines(camera: CameraLines) -> np.ndarray:
    n = camera.lines.shape[0]
    return np.ones(n, dtype=bool) if camera.valid is None else camera.valid


def ball_runs(lines: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, ...]:
    """The ball in a camera's recorded lines ``[S, W]``: the runs of consecutive valid scans
    that show it in one column: each run's first scan, column and length [scans]."""
    black = (lines == 0) & valid[:, None]
    scans = np.flatnonzero(black.any(axis=1))
    column = black[scans].argmax(axis=1)
    new = np.ones(scans.size, dtype=bool)
    new[1:] = (np.diff(scans) != 1) | (np.diff(column) != 0)
    starts = np.flatnonzero(new)
    return scans[starts], column[starts], np.diff(np.append(starts, scans.size))


@pytest.mark.slow
def test_three_cameras_record_a_run_file_in_step_by_frame_id(tmp_path: Path) -> None:
    log = can_log(tmp_path / "can.blf", time.time() - 5.0, 40.0, speed_mps=10.0)
    table = ", ".join(f'{n} = {{device_id = "VikyTL_DEV_{n}", width = {WIDTH}}}' for n in NAMES)
    out = tmp_path / "run.h5"
    result = CliRunner().invoke(
        cli,
        [
            "record", str(out), "--source", "gige",
            "--source-option", 'backend="gentl"',
            "--source-option", f'cti="{VIKY}"',
            "--source-option", f"cameras={{{table}}}",
            "--source-option", f"line_rate_hz={RATE_HZ}",
            "--source-option", f"lines_per_frame={LINES}",
            "--vehicle-source", "can", "--vehicle-option", f"log={log}",
            "--max-scans", "1000", "--block-scans", "250",
        ],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    for name in NAMES:
        assert f"camera {name} (id VikyTL_DEV_{name}): " in result.stdout
    assert "recorded" in result.stdout
    with open_run(out) as run:
        assert run.header.camera_pixels == dict.fromkeys(NAMES, WIDTH)
        blocks = list(run.blocks(500))
    position_m = np.concatenate([b.position_m for b in blocks])
    assert position_m.shape == (1000,)
    np.testing.assert_allclose(np.diff(position_m), 10.0 / RATE_HZ, atol=0.002)
    for name in NAMES:
        lines = np.concatenate([b.cameras[name].lines for b in blocks])
        valid = np.concatenate([valid_lines(b.cameras[name]) for b in blocks])
        # every line from the camera's first whole frame on (nothing lost at 3 frames/s)
        first_whole = int(np.argmax(valid)) + LINES
        lost = np.flatnonzero(~valid[first_whole:]) + first_whole
        assert lost.size == 0, (name, lost, result.stdout)
        start, column, length = (run[1:-1] for run in ball_runs(lines, valid))
        # the ball's rows of every frame arrive whole, and it moves one pixel right and one
        # line down per frame: a frame further on is ``LINES + 1`` scans further per pixel,
        # one frame per frame id, in step (the first and last runs may be cut by the
        # camera's first frame and the recording's end, and are left out)
        assert start.size >= 6, name
        assert (length == BALL).all(), (name, length)
        np.testing.assert_array_equal(np.diff(start), (LINES + 1) * np.diff(column), name)


def test_frames_without_device_timestamps_take_the_hosts_time() -> None:
    parsed = parse_settings(settings())
    camera = GenTLCamera(parsed.cameras[0], parsed)
    before = time.time()
    camera.connect()
    try:
        frames = []
        while len(frames) < 2:
            frame = camera.read(1.0)
            assert frame is not None
            frames.append(frame)
        after = time.time()
    finally:
        camera.disconnect()
    assert camera.frame_id_modulus is None  # not GigE Vision: 64-bit frame ids
    for frame in frames:
        assert before <= frame.host_time_s <= after
        assert frame.device_time_s == frame.host_time_s
        assert frame.complete and frame.data is not None and len(frame.data) == WIDTH * LINES
    assert frames[1].frame_id == frames[0].frame_id + 1
    assert gentl._HARVESTERS == {}  # the producer released with its last camera


def test_a_camera_reopens_while_the_others_acquire() -> None:
    parsed = parse_settings(settings())
    red, green = (GenTLCamera(camera, parsed) for camera in parsed.cameras[:2])
    try:
        red.connect()
        green.connect()  # through the same Harvester: one per producer and process
        red.disconnect()
        assert green.read(1.0) is not None
        red.connect()  # from the device list found when the first camera opened
        assert red.read(1.0) is not None and green.read(1.0) is not None
        red.check()  # it answers a register read
    finally:
        red.disconnect()
        green.disconnect()
    with pytest.raises(CameraUnavailable, match=r"camera .*red.*: not connected"):
        red.check()
    assert gentl._HARVESTERS == {}


def test_a_camera_found_by_serial_number() -> None:
    chosen = settings()
    chosen["cameras"] = {"blue": {"serial": "2", "width": WIDTH}}
    stream = open_gige(chosen)
    try:
        block = next(stream.blocks(50))
    finally:
        stream.close()
    assert block.cameras["blue"].lines.shape == (50, WIDTH)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            {"exposure_us": 50.0},
            r"^camera red \(id VikyTL_DEV_red\): no exposure time feature "
            r"\(ExposureTime or ExposureTimeAbs\)$",
        ),
        (
            {"lines_per_frame": 64},
            r"^camera red \(id VikyTL_DEV_red\): Height = 64 refused \(OutOfRangeException: "
            r"Value = 64 must be equal or greater than Min = 100\.",
        ),
        (
            {"packet_size": 1500},
            r"^camera red \(id VikyTL_DEV_red\): no packet size feature \(GevSCPSPacketSize\)$",
        ),
        (
            {"cameras": {"red": {"serial": "7", "width": WIDTH}}},
            r"^source 'gige': camera red \(serial 7\): not among the GenTL producers' devices "
            r"\(found: VikyTL_DEV_red \(serial 0\), VikyTL_DEV_green \(serial 1\), "
            r"VikyTL_DEV_blue \(serial 2\)\)$",
        ),
    ],
)
def test_what_a_camera_lacks_or_refuses_is_one_line(change: dict[str, Any], message: str) -> None:
    with pytest.raises(UserError, match=message) as error:
        open_gige(settings(**change))
    assert "\n" not in str(error.value)
    assert gentl._HARVESTERS == {}  # released: the next open finds the devices again


def test_a_file_that_is_no_producer_is_one_line(tmp_path: Path) -> None:
    bogus = tmp_path / "bogus.cti"
    bogus.write_text("not a shared library\n")
    with pytest.raises(
        UserError,
        match=rf"^source 'gige': setting cti = '{bogus}': not a GenTL producer "
        r"\(LoadLibraryException: .*file too short",
    ):
        open_gige(settings(cti=str(bogus)))
    assert gentl._HARVESTERS == {}


def test_a_missing_producer_is_one_line_from_the_command(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        cli,
        [
            "record", str(tmp_path / "run.h5"), "--source", "gige",
            "--source-option", 'backend="gentl"',
            "--source-option", f'cti="{tmp_path / "vendor.cti"}"',
            "--source-option", f'cameras={{cam1 = {{serial = "0", width = {WIDTH}}}}}',
            "--source-option", f"line_rate_hz={RATE_HZ}",
        ],
    )  # fmt: skip
    assert result.exit_code != 0
    expected = f"source 'gige': setting cti = '{tmp_path / 'vendor.cti'}': no such file"
    assert expected in result.output
    assert len(result.output.strip().splitlines()) == 1, result.output
