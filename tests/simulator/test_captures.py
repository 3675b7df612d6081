"""Simulated calibration captures: FORMATS.md layout, true matrices, targets where they are."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from catenary_linescan.camera import camera_from_pose
from catenary_linescan.captures import read_capture
from catenary_linescan.simulator.captures import CaptureTool, write_captures
from catenary_linescan.simulator.rig import SimRig
from catenary_linescan.simulator.settings import DEMO_RIG_PATH

TOOL = CaptureTool(heights_mm=(1300.0, 1900.0, 2500.0))


def test_captures_file_and_true_matrices(small_rig: SimRig, tmp_path: Path) -> None:
    capture_path, truth_path = write_captures(tmp_path / "caps.h5", small_rig, TOOL, seed=3)
    capture = read_capture(capture_path)
    assert capture.flat_width_mm == 6.0
    np.testing.assert_array_equal(capture.heights_mm, [1300.0, 1900.0, 2500.0])
    assert capture.target_x_mm.shape == (13,)
    with h5py.File(truth_path) as truth:
        for cam in small_rig.cameras:
            lines = capture.cameras[cam.name].lines
            assert lines.shape == (3, 1024) and lines.dtype == np.uint8
            expected = camera_from_pose(
                cam.name,
                cam.pixels,
                cam.x_mm,
                cam.z_mm,
                cam.tilt_deg,
                cam.focal_px,
                cam.principal_point_px,
                cam.k1,
            )
            np.testing.assert_allclose(
                truth[f"cameras/{cam.name}"].attrs["matrix"], expected.matrix
            )
            assert truth[f"cameras/{cam.name}"].attrs["k1"] == cam.k1
            u = truth[f"cameras/{cam.name}/u_px"][()]
            assert u.shape == (3, 13) and np.isfinite(u).all()


def test_targets_are_bright_faces_where_the_truth_says(small_rig: SimRig, tmp_path: Path) -> None:
    capture_path, truth_path = write_captures(tmp_path / "caps.h5", small_rig, TOOL, seed=3)
    capture = read_capture(capture_path)
    with h5py.File(truth_path) as truth:
        for cam in small_rig.cameras:
            lines = capture.cameras[cam.name].lines.astype(float)
            u = truth[f"cameras/{cam.name}/u_px"][()]
            for h in range(3):
                background = np.median(lines[h])
                peaks = lines[h, np.round(u[h]).astype(int)]
                assert np.all(peaks > background + 15), (cam.name, h)
                # between targets the line is dark (the bar is black)
                between = np.round(0.5 * (u[h, 1:] + u[h, :-1])).astype(int)
                assert np.all(lines[h, between] < background + 15)


@pytest.mark.skipif(not DEMO_RIG_PATH.with_name("demo-captures.h5").exists(), reason="not built")
def test_shipped_demo_captures_match_the_demo_rig(demo_rig: SimRig) -> None:
    shipped = DEMO_RIG_PATH.with_name("demo-captures.h5")
    capture = read_capture(shipped)
    assert set(capture.cameras) == {c.name for c in demo_rig.cameras}
    with h5py.File(shipped.with_name("demo-captures.truth.h5")) as truth:
        for cam in demo_rig.cameras:
            np.testing.assert_allclose(
                truth[f"cameras/{cam.name}"].attrs["matrix"], cam.model().matrix
            )
