"""``catenary calibrate`` end to end on the shipped demo captures (simulated, with truth)."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from catenary.cli import cli
from catenary_linescan.camera import LineScanCamera
from catenary_linescan.captures import write_points_csv
from catenary_linescan.rig import Rig, read_rig
from catenary_linescan.simulator.settings import DEMO_RIG_PATH
from catenary_linescan.triangulation import triangulate

CAPTURES = DEMO_RIG_PATH.with_name("demo-captures.h5")
TRUTH = DEMO_RIG_PATH.with_name("demo-captures.truth.h5")


def _true_cameras() -> dict[str, LineScanCamera]:
    with h5py.File(TRUTH, "r") as f:
        return {
            name: LineScanCamera(
                name, int(g.attrs["pixels"]), np.asarray(g.attrs["matrix"]), float(g.attrs["k1"])
            )
            for name, g in f["cameras"].items()
        }


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Rig, str]:
    out = tmp_path_factory.mktemp("cal") / "rig.toml"
    result = CliRunner().invoke(
        cli, ["calibrate", str(CAPTURES), "--vehicle", str(DEMO_RIG_PATH), "-o", str(out)]
    )
    assert result.exit_code == 0, result.output
    return read_rig(out), result.output


def test_reprojection_rms_under_a_third_of_a_pixel(calibrated: tuple[Rig, str]) -> None:
    rig, output = calibrated
    assert list(rig.cameras) == ["cam1", "cam2", "cam3", "cam4"]
    for camera in rig.cameras.values():
        assert camera.reprojection_rms_px < 0.3
        assert camera.measured_resolution is not None
    assert "rig calibration written to" in output


def test_interpolated_table_matches_the_true_resolution(calibrated: tuple[Rig, str]) -> None:
    rig, _ = calibrated
    x, z = np.meshgrid(np.linspace(-400.0, 400.0, 41), np.linspace(1300.0, 2500.0, 31))
    for name, true in _true_cameras().items():
        table = rig.cameras[name].resolution
        error = table.at(x, z) / true.resolution_mm_per_px(x, z) - 1.0
        assert np.max(np.abs(error)) < 0.005, name


def test_calibrated_rig_triangulates_within_a_millimetre(calibrated: tuple[Rig, str]) -> None:
    rig, _ = calibrated
    true = _true_cameras()
    x, z = (a.ravel() for a in np.meshgrid(np.linspace(-400, 400, 17), np.linspace(1300, 2500, 13)))
    u = np.stack([true[name].project(x, z) for name in rig.cameras], axis=1)
    result = triangulate(rig.camera_models, u)
    assert np.max(np.hypot(result.x_mm - x, result.z_mm - z)) < 1.0


def test_point_list_needs_pixels_and_calibrates_with_them(tmp_path: Path) -> None:
    from catenary_linescan.captures import CalibrationPoints

    true = _true_cameras()
    x, z = (a.ravel() for a in np.meshgrid(np.linspace(-500, 500, 11), np.linspace(1300, 2500, 7)))
    names = np.repeat(list(true), x.size)
    u = np.concatenate([true[n].project(x, z) for n in true])
    csv = tmp_path / "points.csv"
    write_points_csv(csv, CalibrationPoints(names, np.tile(x, 4), np.tile(z, 4), u))
    out = tmp_path / "rig.toml"
    args = ["calibrate", str(csv), "--vehicle", str(DEMO_RIG_PATH), "-o", str(out)]
    refused = CliRunner().invoke(cli, args)
    assert refused.exit_code == 1
    assert "--pixels" in refused.output and not out.exists()
    result = CliRunner().invoke(cli, [*args, "--pixels", "4096"])
    assert result.exit_code == 0, result.output
    assert read_rig(out).cameras["cam1"].reprojection_rms_px < 0.01


@pytest.mark.parametrize("which", ["captures", "vehicle"])
def test_wrong_files_are_one_line_errors(tmp_path: Path, which: str) -> None:
    wrong = tmp_path / "wrong.h5"
    wrong.write_text("this is not HDF5")
    captures = wrong if which == "captures" else CAPTURES
    vehicle = wrong if which == "vehicle" else DEMO_RIG_PATH
    out = tmp_path / "rig.toml"
    result = CliRunner().invoke(
        cli, ["calibrate", str(captures), "--vehicle", str(vehicle), "-o", str(out)]
    )
    assert result.exit_code == 1
    assert "wrong.h5" in result.output and "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1
    assert not out.exists()
