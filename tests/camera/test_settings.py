"""The ``gige`` source's settings: one-line errors naming the key and the value."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from catenary.errors import UserError
from catenary_camera.settings import parse_settings


def base(**extra: Any) -> dict[str, Any]:
    return {
        "cameras": {
            "cam1": {"address": "192.168.10.11", "width": 4096},
            "cam2": {"serial": "LS-0042", "width": 2048, "offset_px": 1024},
        },
        "line_rate_hz": 5300,
        **extra,
    }


def test_defaults_and_shared_camera_keys() -> None:
    parsed = parse_settings(base(pixel_format="Mono12", exposure_us=80))
    cam1, cam2 = parsed.cameras
    assert (cam1.address, cam1.width, cam1.offset_px) == ("192.168.10.11", 4096, 0)
    assert (cam2.serial, cam2.offset_px) == ("LS-0042", 1024)
    assert cam1.pixel_format == cam2.pixel_format == "Mono12"
    assert cam2.exposure_us == 80.0
    assert parsed.trigger == "free" and parsed.nominal_rate_hz == 5300.0
    assert parsed.frame_period_s == pytest.approx(256 / 5300)
    assert parsed.arrival_lag_frames == 1.0  # a frame is sent once its lines are all taken


def test_encoder_trigger() -> None:
    settings = base(trigger="encoder", metres_per_line=0.013, nominal_rate_hz=5300)
    del settings["line_rate_hz"]
    parsed = parse_settings(settings)
    assert (parsed.trigger, parsed.trigger_line, parsed.metres_per_line) == (
        "encoder",
        "Line0",
        0.013,
    )


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"cameras": {}}, r"setting cameras = \{\}: expected a table"),
        ({"colour": 1}, r"unknown setting 'colour'"),
        ({"line_rate_hz": -5}, r"setting line_rate_hz = -5: expected a positive number"),
        ({"line_rate_hz": None}, r"trigger 'free' needs line_rate_hz"),
        ({"trigger": "pulse"}, r"setting trigger = 'pulse': expected free or encoder"),
        ({"metres_per_line": 0.01}, r"metres_per_line is for trigger 'encoder'"),
        ({"lines_per_frame": 2.5}, r"lines_per_frame = 2.5: expected a positive integer"),
        ({"pixel_format": "RGB8"}, r"cameras.cam1.pixel_format = 'RGB8': expected one of Mono8"),
        ({"packet_size": 100}, r"cameras.cam1.packet_size = 100: expected 576-16384 bytes"),
        ({"direction": "up"}, r"direction = 'up'"),
        ({"arrival_lag_frames": -1}, r"arrival_lag_frames = -1: expected a number of frames"),
        ({"backend": "pylon"}, r"backend = 'pylon': expected one of aravis, gentl"),
        ({"cti": "/x.cti"}, r"setting cti is for backend 'gentl', not 'aravis'$"),
    ],
)
def test_wrong_settings_are_one_line(change: dict[str, Any], message: str) -> None:
    settings = {**base(), **change}
    settings = {k: v for k, v in settings.items() if v is not None}
    with pytest.raises(UserError, match=message) as error:
        parse_settings(settings)
    assert "\n" not in str(error.value)


@pytest.mark.parametrize(
    ("camera", "message"),
    [
        ({"width": 4096}, r"camera 'cam1' needs one of cameras.cam1.address or .serial"),
        ({"address": "a", "serial": "b", "width": 1}, r"needs one of"),
        ({"address": "10.0.0.1"}, r"camera 'cam1' needs cameras.cam1.width"),
        ({"address": "10.0.0.1", "width": 0}, r"cameras.cam1.width = 0"),
        ({"address": "10.0.0.1", "width": 8, "offset_px": -1}, r"cameras.cam1.offset_px = -1"),
        ({"address": " 10.0.0.1", "width": 8}, r"cameras.cam1.address = ' 10.0.0.1'"),
        ({"address": "10.0.0.1", "width": 8, "gain": 2}, r"unknown setting cameras.cam1.gain"),
    ],
)
def test_wrong_camera_settings_are_one_line(camera: dict[str, Any], message: str) -> None:
    with pytest.raises(UserError, match=message):
        parse_settings({"cameras": {"cam1": camera}, "line_rate_hz": 1000})


def test_two_cameras_cannot_share_a_device() -> None:
    settings = base()
    settings["cameras"]["cam2"] = {"address": "192.168.10.11", "width": 8}
    with pytest.raises(UserError, match=r"cameras 'cam1' and 'cam2' share address"):
        parse_settings(settings)


def gentl(tmp_path: Path, **extra: Any) -> dict[str, Any]:
    (tmp_path / "producer.cti").write_bytes(b"")
    return {
        "backend": "gentl",
        "cti": str(tmp_path / "producer.cti"),
        "cameras": {
            "cam1": {"serial": "0", "width": 400},
            "cam2": {"device_id": "VikyTL_DEV_green", "width": 400},
        },
        "line_rate_hz": 2000,
        **extra,
    }


def test_gentl_cameras_by_serial_or_device_id(tmp_path: Path) -> None:
    parsed = parse_settings(gentl(tmp_path))
    assert parsed.backend == "gentl" and parsed.cti == (str(tmp_path / "producer.cti"),)
    assert [camera.device for camera in parsed.cameras] == [
        "cam1 (serial 0)",
        "cam2 (id VikyTL_DEV_green)",
    ]


def test_gentl_producers_from_the_standard_variable(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    folder = tmp_path / "producers"
    folder.mkdir()
    for name in ("b.cti", "a.cti", "notes.txt"):
        (folder / name).write_bytes(b"")
    settings = gentl(tmp_path)
    del settings["cti"]
    monkeypatch.setenv("GENICAM_GENTL64_PATH", f"/nonexistent:{folder}")
    assert parse_settings(settings).cti == (str(folder / "a.cti"), str(folder / "b.cti"))
    monkeypatch.setenv("GENICAM_GENTL64_PATH", "/nonexistent")
    with pytest.raises(UserError, match=r"needs setting cti .* \(GENICAM_GENTL64_PATH = '/none"):
        parse_settings(settings)
    monkeypatch.delenv("GENICAM_GENTL64_PATH")
    with pytest.raises(UserError, match=r"GENICAM_GENTL64_PATH = ''\)$"):
        parse_settings(settings)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"cti": "/nowhere/producer.cti"}, r"setting cti = '/nowhere/producer.cti': no such file$"),
        ({"cti": []}, r"setting cti = \[\]: expected a GenTL producer's .cti file or a list"),
        ({"cti": 3}, r"setting cti = 3: expected"),
        (
            {"cameras": {"c": {"address": "10.0.0.1", "width": 8}}},
            r"setting cameras.c.address is not for backend 'gentl' \(it names a device by "
            r"serial or device_id\)$",
        ),
        (
            {"cameras": {"c": {"width": 8}}},
            r"camera 'c' needs one of cameras.c.serial or .device_id$",
        ),
        (
            {"cameras": {"c": {"device_id": "x", "width": 8}, "d": {"device_id": "x", "width": 8}}},
            r"cameras 'c' and 'd' share device_id 'x'$",
        ),
    ],
)
def test_wrong_gentl_settings_are_one_line(
    tmp_path: Path, change: dict[str, Any], message: str
) -> None:
    with pytest.raises(UserError, match=message) as error:
        parse_settings({**gentl(tmp_path), **change})
    assert "\n" not in str(error.value)


def test_a_gentl_device_id_is_not_for_aravis() -> None:
    settings = base()
    settings["cameras"]["cam1"] = {"device_id": "DEV_1", "width": 8}
    with pytest.raises(UserError, match=r"cameras.cam1.device_id is not for backend 'aravis'"):
        parse_settings(settings)
