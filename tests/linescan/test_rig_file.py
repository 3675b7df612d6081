"""The rig calibration TOML: round trip and one-line errors naming the file and key."""

from __future__ import annotations

import tomllib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from catenary.domain import VehicleGeometry
from catenary.errors import FormatError
from catenary_linescan.calibration import resolution_table_from_camera
from catenary_linescan.camera import camera_from_pose
from catenary_linescan.rig import Rig, RigCamera, read_rig, write_rig

VEHICLE = VehicleGeometry("demo", 3900.0, 1100.0, 1800.0)


def _rig() -> Rig:
    cameras = {}
    for name, x, tilt in (("left", -500.0, 12.0), ("right", 500.0, -12.0)):
        camera = camera_from_pose(name, 4096, x, 0.0, tilt, 5000.0, 2047.5, k1=-0.01)
        table = resolution_table_from_camera(
            camera, np.arange(-600.0, 601.0, 200.0), np.arange(1300.0, 2501.0, 400.0)
        )
        cameras[name] = RigCamera(camera, table, 0.08, 0.31)
    return Rig(VEHICLE, cameras, created_at="2026-11-23T15:00:00Z", source="captures.h5")


def test_round_trip_keeps_matrices_tables_and_figures(tmp_path: Path) -> None:
    path = tmp_path / "rig.toml"
    rig = _rig()
    write_rig(path, rig)
    back = read_rig(path)
    assert back.vehicle == VEHICLE
    assert list(back.cameras) == ["left", "right"]
    for name, original in rig.cameras.items():
        read = back.cameras[name]
        np.testing.assert_allclose(read.camera.matrix, original.camera.normalised().matrix)
        assert read.camera.k1 == pytest.approx(-0.01)
        np.testing.assert_allclose(read.resolution.mm_per_px, original.resolution.mm_per_px)
        assert read.reprojection_rms_px == pytest.approx(0.08)
        u = original.camera.project(100.0, 1800.0)
        assert read.camera.project(100.0, 1800.0) == pytest.approx(u, abs=1e-6)


def test_missing_table_defaults_to_the_camera_model(tmp_path: Path) -> None:
    path = tmp_path / "rig.toml"
    write_rig(path, _rig())
    data = tomllib.loads(path.read_text())
    for camera in data["cameras"]:
        del camera["resolution"]
    path.write_text(tomli_w.dumps(data))
    back = read_rig(path)
    camera = back.cameras["left"].camera
    table = back.cameras["left"].resolution
    expected = camera.resolution_mm_per_px(0.0, 1900.0)
    assert table.at(0.0, 1900.0) == pytest.approx(expected, rel=1e-3)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.replace('format = "catenary-rig"', 'format = "other"'), "format"),
        (lambda t: t.replace("format_version = 1", "format_version = 7"), "format_version 7"),
        (lambda t: t.replace("roof_height_mm = 3900.0", "roof_height_mm = -1"), "roof_height_mm"),
        (lambda t: t.replace("pixels = 4096", "pixels = 'many'", 1), "cameras[left].pixels"),
        (lambda t: t.replace('name = "right"', 'name = "left"'), "appears twice"),
        (lambda t: t.replace("[[", "[x[", 1), "not valid TOML"),
    ],
)
def test_malformed_rig_names_file_and_key(
    tmp_path: Path, edit: Callable[[str], str], message: str
) -> None:
    path = tmp_path / "bad-rig.toml"
    write_rig(path, _rig())
    path.write_text(edit(path.read_text()))
    with pytest.raises(FormatError) as caught:
        read_rig(path)
    text = str(caught.value)
    assert "bad-rig.toml" in text and message in text and "\n" not in text.strip()
