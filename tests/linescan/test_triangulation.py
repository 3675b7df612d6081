"""Triangulation: the paper's two-camera closed form and the N-camera least squares."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from catenary_linescan.camera import LineScanCamera, camera_from_pose
from catenary_linescan.triangulation import triangulate, triangulate_pair

PIXELS = 4096
FOCAL_PX = 5000.0
CAMERA_X_MM = (-700.0, -250.0, 250.0, 700.0)
NOISE_PX = 0.1


def demo_rig(k1: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)) -> list[LineScanCamera]:
    """Four cameras on the roof, each tilted to centre x ±600 mm at 1300-2500 mm."""
    corners_x = np.array([-600.0, 600.0, -600.0, 600.0])
    corners_z = np.array([1300.0, 1300.0, 2500.0, 2500.0])
    cameras = []
    for index, (x, k) in enumerate(zip(CAMERA_X_MM, k1, strict=True)):
        angles = np.degrees(np.arctan2(corners_x - x, corners_z))
        tilt = 0.5 * (angles.min() + angles.max())
        cameras.append(
            camera_from_pose(f"cam{index}", PIXELS, x, 0.0, tilt, FOCAL_PX, 2047.5 + 10 * index, k)
        )
    return cameras


def points(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(-400.0, 400.0, n), rng.uniform(1300.0, 2500.0, n)


def observe(cameras: list[LineScanCamera], x: np.ndarray, z: np.ndarray) -> np.ndarray:
    return np.stack([camera.project(x, z) for camera in cameras], axis=1)


@settings(max_examples=40, deadline=None)
@given(
    x=st.floats(-400.0, 400.0),
    z=st.floats(1300.0, 2500.0),
    pair=st.sampled_from(list(itertools.combinations(range(4), 2))),
)
def test_pair_closed_form_is_exact_without_noise(x: float, z: float, pair: tuple[int, int]):
    cameras = demo_rig(k1=(-0.02, 0.0, 0.01, -0.01))
    a, b = (cameras[i] for i in pair)
    x_mm, z_mm = triangulate_pair(a, b, a.project(x, z), b.project(x, z))
    assert x_mm == pytest.approx(x, abs=1e-6)
    assert z_mm == pytest.approx(z, abs=1e-6)


def test_pair_with_noise_stays_within_1_mm():
    cameras = demo_rig()
    x, z = points(2000, seed=1)
    noisy = observe(cameras, x, z) + np.random.default_rng(2).normal(0.0, NOISE_PX, (2000, 4))
    for i, j in [(0, 3), (0, 2), (1, 3)]:  # pairs with a baseline of 950 mm or more
        x_mm, z_mm = triangulate_pair(cameras[i], cameras[j], noisy[:, i], noisy[:, j])
        assert np.max(np.abs(x_mm - x)) < 1.0
        assert np.max(np.abs(z_mm - z)) < 1.0
    # the two inner cameras (500 mm apart) are worse in height, as the covariance says
    result = triangulate([cameras[1], cameras[2]], noisy[:, 1:3])
    error = np.hypot(result.x_mm - x, result.z_mm - z)
    assert np.max(np.abs(result.z_mm - z) / result.sigma_z_mm) < 5.0
    assert np.max(error) < 2.0


def test_pair_broadcasts_and_flags_parallel_rays():
    camera = demo_rig()[0]
    u = np.linspace(100.0, 4000.0, 7)
    x_mm, z_mm = triangulate_pair(camera, camera, u, u)  # the same ray twice
    assert np.all(np.isnan(x_mm)) and np.all(np.isnan(z_mm))
    a, b = demo_rig()[0], demo_rig()[3]
    x_mm, _ = triangulate_pair(a, b, a.project(0.0, 2000.0), np.array([[1500.0], [2500.0]]))
    assert x_mm.shape == (2, 1)


def test_n_view_recovers_positions_and_a_calibrated_uncertainty():
    cameras = demo_rig(k1=(-0.02, 0.0, 0.01, -0.01))
    n = 4000
    x, z = points(n, seed=3)
    clean = observe(cameras, x, z)
    noisy = clean + np.random.default_rng(4).normal(0.0, NOISE_PX, clean.shape)
    result = triangulate(cameras, noisy, sigma_px=NOISE_PX)
    assert np.all(result.cameras_used == 4)
    assert np.max(np.abs(result.x_mm - x)) < 1.0
    assert np.max(np.abs(result.z_mm - z)) < 1.0
    # the covariance describes the actual scatter (normalised errors have unit spread)
    assert np.std((result.x_mm - x) / result.sigma_x_mm) == pytest.approx(1.0, abs=0.1)
    assert np.std((result.z_mm - z) / result.sigma_z_mm) == pytest.approx(1.0, abs=0.1)
    # four cameras, two unknowns: E[rms²] = sigma² · (4 - 2) / 4
    mean_square = np.mean(result.rms_reprojection_px**2)
    assert mean_square == pytest.approx(NOISE_PX**2 / 2, rel=0.1)
    exact = triangulate(cameras, clean)
    assert np.max(np.abs(exact.x_mm - x)) < 1e-6
    assert np.max(np.abs(exact.z_mm - z)) < 1e-6
    assert np.max(exact.rms_reprojection_px) < 1e-6


def test_a_blinded_camera_is_left_out():
    cameras = demo_rig()
    x, z = points(1000, seed=5)
    noisy = observe(cameras, x, z) + np.random.default_rng(6).normal(0.0, NOISE_PX, (1000, 4))
    for blind in range(4):
        u = noisy.copy()
        u[:, blind] = np.nan
        result = triangulate(cameras, u)
        assert np.all(result.cameras_used == 3)
        assert np.max(np.abs(result.x_mm - x)) < 1.0
        assert np.max(np.abs(result.z_mm - z)) < 1.0


def test_points_seen_by_fewer_than_two_cameras_are_nan():
    cameras = demo_rig()
    x, z = points(4, seed=7)
    u = observe(cameras, x, z)
    u[0, :] = np.nan
    u[1, 1:] = np.nan
    u[2, 2:] = np.nan
    result = triangulate(cameras, u)
    np.testing.assert_array_equal(result.cameras_used, [0, 1, 2, 4])
    for field in ("x_mm", "z_mm", "rms_reprojection_px", "sigma_x_mm", "sigma_z_mm"):
        values = getattr(result, field)
        assert values.shape == (4,)
        assert np.all(np.isnan(values[:2])) and np.all(np.isfinite(values[2:])), field
    assert result.x_mm[2] == pytest.approx(x[2], abs=1e-6)


def test_two_cameras_agree_with_the_closed_form():
    cameras = demo_rig(k1=(-0.02, 0.0, 0.0, 0.01))
    x, z = points(500, seed=8)
    noisy = observe(cameras, x, z) + np.random.default_rng(9).normal(0.0, NOISE_PX, (500, 4))
    pair = [cameras[0], cameras[3]]
    result = triangulate(pair, noisy[:, [0, 3]])
    x_mm, z_mm = triangulate_pair(cameras[0], cameras[3], noisy[:, 0], noisy[:, 3])
    np.testing.assert_allclose(result.x_mm, x_mm, atol=1e-6)
    np.testing.assert_allclose(result.z_mm, z_mm, atol=1e-6)
    np.testing.assert_allclose(result.rms_reprojection_px, 0.0, atol=1e-6)


def test_empty_input_and_shape_check():
    cameras = demo_rig()
    result = triangulate(cameras, np.zeros((0, 4)))
    assert result.x_mm.shape == (0,) and result.cameras_used.shape == (0,)
    with pytest.raises(ValueError, match="expected"):
        triangulate(cameras, np.zeros((3, 2)))
