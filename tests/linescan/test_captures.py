"""Calibration captures: the HDF5 and CSV files, and measuring the targets in the lines."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from catenary.domain import CameraLines
from catenary.errors import FormatError, UserError
from catenary_linescan.calibration import build_resolution_table, calibrate_camera
from catenary_linescan.camera import LineScanCamera, camera_from_pose
from catenary_linescan.captures import (
    CalibrationCapture,
    CalibrationPoints,
    assign_targets,
    estimate_target_mapping,
    measure_capture,
    measure_targets,
    read_capture,
    read_points_csv,
    write_capture,
    write_points_csv,
)
from catenary_linescan.triangulation import triangulate

PIXELS = 4096
FOCAL_PX = 5000.0
CAMERA_X_MM = (-700.0, -250.0, 250.0, 700.0)
TARGETS_X_MM = np.arange(-600.0, 601.0, 100.0)
HEIGHTS_MM = np.arange(1300.0, 2501.0, 100.0)
FLAT_WIDTH_MM = 6.0


def demo_rig(k1: float = 0.0) -> list[LineScanCamera]:
    """Four cameras on the roof, each tilted to centre x ±600 mm at 1300-2500 mm."""
    corners_x = np.array([-600.0, 600.0, -600.0, 600.0])
    corners_z = np.array([1300.0, 1300.0, 2500.0, 2500.0])
    cameras = []
    for index, x in enumerate(CAMERA_X_MM):
        angles = np.degrees(np.arctan2(corners_x - x, corners_z))
        tilt = 0.5 * (angles.min() + angles.max())
        u0 = 2047.5 + 15.0 * (index - 1.5)
        cameras.append(camera_from_pose(f"cam{index}", PIXELS, x, 0.0, tilt, FOCAL_PX, u0, k1))
    return cameras


def render_line(
    face_left_px: np.ndarray,
    face_right_px: np.ndarray,
    *,
    side_px: np.ndarray | float = 8.0,
    bit_depth: int = 8,
    blur_px: float = 1.0,
    noise: float = 0.005,
    rng: np.random.Generator | None = None,
    pixels: int = PIXELS,
) -> np.ndarray:
    """A line of targets: bright flat faces (0.8 of full scale) flanked by dimmer sides
    (0.35) on a sloping background (0.12-0.17); Gaussian blur, pixel integration (pixel
    ``i`` covers ``[i - 0.5, i + 0.5)``), noise as a fraction of full scale, quantisation."""
    supersample = 8
    fine = (np.arange(pixels * supersample) + 0.5) / supersample - 0.5
    at = fine[:, np.newaxis]
    left, right = np.asarray(face_left_px), np.asarray(face_right_px)
    face = (at >= left) & (at < right)
    side = ((at >= left - side_px) & (at < left)) | ((at >= right) & (at < right + side_px))
    background = 0.12 + 0.05 * fine / pixels
    scene = background + (0.8 - background) * face.any(axis=1)
    scene += (0.35 - background) * (side.any(axis=1) & ~face.any(axis=1))
    if blur_px > 0:
        scene = ndimage.gaussian_filter1d(scene, blur_px * supersample, mode="nearest")
    line = scene.reshape(pixels, supersample).mean(axis=1)
    if rng is not None:
        line = line + rng.normal(0.0, noise, pixels)
    full = 2**bit_depth - 1
    dtype = np.uint8 if bit_depth <= 8 else np.uint16
    return np.clip(np.round(line * full), 0, full).astype(dtype)


def render_capture(
    cameras: list[LineScanCamera], rng: np.random.Generator, bit_depth: int = 12
) -> CalibrationCapture:
    """What each camera sees of the calibration bar (6 mm faces on 14 mm targets)."""
    lines = {}
    for camera in cameras:
        rows = []
        for z in HEIGHTS_MM:
            a = camera.project(TARGETS_X_MM - FLAT_WIDTH_MM / 2, z)
            b = camera.project(TARGETS_X_MM + FLAT_WIDTH_MM / 2, z)
            body = np.abs(
                camera.project(TARGETS_X_MM + 7.0, z) - camera.project(TARGETS_X_MM - 7, z)
            )
            left, right = np.minimum(a, b), np.maximum(a, b)
            side = (body - (right - left)) / 2
            rows.append(render_line(left, right, side_px=side, bit_depth=bit_depth, rng=rng))
        lines[camera.name] = CameraLines(np.array(rows), bit_depth)
    return CalibrationCapture(FLAT_WIDTH_MM, TARGETS_X_MM, HEIGHTS_MM, lines)


def small_capture(dtype=np.uint8, bit_depth: int = 8) -> CalibrationCapture:
    rng = np.random.default_rng(0)
    lines = {
        name: CameraLines(rng.integers(0, 2**bit_depth, (3, 64)).astype(dtype), bit_depth)
        for name in ("left", "right")
    }
    return CalibrationCapture(
        6.0, np.array([-100.0, 0.0, 100.0]), np.array([1300.0, 1800.0, 2500.0]), lines
    )


# -- files ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(("dtype", "bit_depth"), [(np.uint8, 8), (np.uint16, 12), (np.uint16, 16)])
def test_capture_round_trips_through_hdf5(tmp_path: Path, dtype, bit_depth: int):
    capture = small_capture(dtype, bit_depth)
    path = tmp_path / "capture.h5"
    write_capture(path, capture)
    back = read_capture(path)
    assert back.flat_width_mm == capture.flat_width_mm
    np.testing.assert_array_equal(back.target_x_mm, capture.target_x_mm)
    np.testing.assert_array_equal(back.heights_mm, capture.heights_mm)
    assert list(back.cameras) == list(capture.cameras)
    for name, lines in capture.cameras.items():
        assert back.cameras[name].bit_depth == bit_depth
        assert back.cameras[name].lines.dtype == dtype
        np.testing.assert_array_equal(back.cameras[name].lines, lines.lines)
    assert [p.name for p in tmp_path.iterdir()] == ["capture.h5"]  # no temporary left behind


def _drop(name: str) -> Callable[[h5py.File], None]:
    def mutate(file: h5py.File) -> None:
        del file[name]

    return mutate


def _set_attr(node: str, name: str, value: object) -> Callable[[h5py.File], None]:
    def mutate(file: h5py.File) -> None:
        file[node].attrs[name] = value

    return mutate


def _del_attr(node: str, name: str) -> Callable[[h5py.File], None]:
    def mutate(file: h5py.File) -> None:
        del file[node].attrs[name]

    return mutate


def _replace(
    name: str, data: np.ndarray, bit_depth: int | None = None
) -> Callable[[h5py.File], None]:
    def mutate(file: h5py.File) -> None:
        del file[name]
        dataset = file.create_dataset(name, data=data)
        if bit_depth is not None:
            dataset.attrs["bit_depth"] = bit_depth

    return mutate


MALFORMED = {
    "missing targets": (_drop("targets/x_mm"), "/targets/x_mm"),
    "missing heights": (_drop("heights_mm"), "/heights_mm"),
    "missing cameras": (_drop("cameras"), "/cameras"),
    "missing lines": (_drop("cameras/left/lines"), "/cameras/left/lines"),
    "wrong format": (_set_attr("/", "format", "catenary-run"), "format"),
    "wrong version": (_set_attr("/", "format_version", 2), "format_version"),
    "version not an integer": (_set_attr("/", "format_version", "1"), "format_version"),
    "missing version": (_del_attr("/", "format_version"), "format_version"),
    "missing flat width": (_del_attr("/", "flat_width_mm"), "flat_width_mm"),
    "negative flat width": (_set_attr("/", "flat_width_mm", -6.0), "flat_width_mm"),
    "missing bit depth": (_del_attr("cameras/left/lines", "bit_depth"), "bit_depth"),
    "bit depth not an integer": (_set_attr("cameras/left/lines", "bit_depth", "8"), "bit_depth"),
    "bit depth too large": (_set_attr("cameras/left/lines", "bit_depth", 12), "bit_depth"),
    "lines wrong shape": (
        _replace("cameras/left/lines", np.zeros((2, 64), np.uint8), 8),
        "/cameras/left/lines",
    ),
    "lines one-dimensional": (
        _replace("cameras/left/lines", np.zeros(64, np.uint8), 8),
        "/cameras/left/lines",
    ),
    "lines wrong dtype": (
        _replace("cameras/left/lines", np.zeros((3, 64), np.float32), 8),
        "/cameras/left/lines",
    ),
    "targets wrong dtype": (_replace("targets/x_mm", np.array([b"a", b"b"])), "/targets/x_mm"),
    "targets wrong shape": (_replace("targets/x_mm", np.zeros((3, 2))), "/targets/x_mm"),
    "heights not finite": (
        _replace("heights_mm", np.array([1300.0, np.nan, 2500.0])),
        "heights_mm",
    ),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_capture_names_the_file_and_field(tmp_path: Path, case: str):
    mutate, field = MALFORMED[case]
    path = tmp_path / "capture.h5"
    write_capture(path, small_capture())
    with h5py.File(path, "r+") as file:
        mutate(file)
    with pytest.raises(FormatError) as raised:
        read_capture(path)
    message = str(raised.value)
    assert str(path) in message and field in message, message
    assert "\n" not in message


def test_not_hdf5_is_a_format_error(tmp_path: Path):
    path = tmp_path / "capture.h5"
    path.write_text("camera,x_mm\n")
    with pytest.raises(FormatError, match="HDF5"):
        read_capture(path)
    with pytest.raises(FormatError, match="HDF5"):
        read_capture(tmp_path / "missing.h5")


def test_extra_groups_and_attributes_are_ignored(tmp_path: Path):
    path = tmp_path / "capture.h5"
    write_capture(path, small_capture())
    with h5py.File(path, "r+") as file:
        file.attrs["operator"] = "night shift"
        file.create_dataset("notes/temperature_c", data=[21.5])
    assert set(read_capture(path).cameras) == {"left", "right"}


@settings(max_examples=25, deadline=None)
@given(
    values=st.lists(
        st.tuples(
            st.sampled_from(["left", "right", "cam 3", "ü-cam"]),
            st.floats(-1e4, 1e4, allow_nan=False),
            st.floats(-1e4, 1e4, allow_nan=False),
            st.floats(-1e4, 1e4, allow_nan=False),
        ),
        min_size=1,
        max_size=30,
    )
)
def test_points_round_trip_through_csv(tmp_path_factory: pytest.TempPathFactory, values):
    path = tmp_path_factory.mktemp("csv") / "points.csv"
    points = CalibrationPoints(
        np.array([v[0] for v in values]),
        np.array([v[1] for v in values]),
        np.array([v[2] for v in values]),
        np.array([v[3] for v in values]),
    )
    write_points_csv(path, points)
    back = read_points_csv(path)
    np.testing.assert_array_equal(back.camera, points.camera)
    for field in ("x_mm", "z_mm", "u_px"):
        np.testing.assert_array_equal(getattr(back, field), getattr(points, field))
    first = points.cameras[0]
    assert back.cameras == points.cameras
    np.testing.assert_array_equal(back.of_camera(first)[2], points.u_px[points.camera == first])


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("camera,x_mm,z_mm\nleft,1,2\n", "u_px"),
        ("camera,x_mm,z_mm,u_px\nleft,1,2,abc\n", "line 2: u_px 'abc'"),
        ("camera,x_mm,z_mm,u_px\nleft,1,2,3\nleft,1,nan,3\n", "line 3: z_mm 'nan'"),
        ("camera,x_mm,z_mm,u_px\n,1,2,3\n", "line 2: empty camera"),
        ("camera,x_mm,z_mm,u_px\n", "no calibration points"),
        ("", "missing column"),
    ],
)
def test_malformed_point_list(tmp_path: Path, text: str, expected: str):
    path = tmp_path / "points.csv"
    path.write_text(text)
    with pytest.raises(FormatError, match=expected) as raised:
        read_points_csv(path)
    assert str(path) in str(raised.value)


def test_point_list_columns_in_any_order_with_extras(tmp_path: Path):
    path = tmp_path / "points.csv"
    path.write_text("u_px, note ,camera,z_mm,x_mm\n2047.25,a,left,1300,-100.5\n")
    points = read_points_csv(path)
    assert points.camera.tolist() == ["left"]
    assert (points.x_mm[0], points.z_mm[0], points.u_px[0]) == (-100.5, 1300.0, 2047.25)


# -- measuring the targets -----------------------------------------------------------------------


@pytest.mark.parametrize("bit_depth", [8, 12, 16])
@pytest.mark.parametrize("blur_px", [0.5, 1.0, 1.5])
def test_faces_are_measured_to_a_tenth_of_a_pixel(bit_depth: int, blur_px: float):
    rng = np.random.default_rng(bit_depth * 10 + int(blur_px * 2))
    centre_errors, width_errors = [], []
    for _ in range(5):
        centre = np.sort(np.linspace(150.0, 3900.0, 12) + rng.uniform(-30.0, 30.0, 12))
        width = rng.uniform(9.0, 26.0, 12)  # 6 mm at 0.23-0.65 mm/px
        line = render_line(
            centre - width / 2, centre + width / 2, bit_depth=bit_depth, blur_px=blur_px, rng=rng
        )
        found_centre, found_width, contrast = measure_targets(line, bit_depth)
        assert found_centre.shape == (12,)
        assert np.all(np.abs(contrast - 0.65) < 0.1)
        centre_errors.append(found_centre - centre)
        width_errors.append(found_width - width)
    centre_error, width_error = np.concatenate(centre_errors), np.concatenate(width_errors)
    assert np.sqrt(np.mean(centre_error**2)) < 0.08
    assert np.max(np.abs(centre_error)) < 0.3
    assert np.sqrt(np.mean(width_error**2)) < 0.2
    assert np.max(np.abs(width_error)) < 0.7


def test_8_and_16_bit_lines_give_the_same_faces():
    rng = np.random.default_rng(31)
    centre = np.array([400.0, 1700.3, 3001.7])
    line16 = render_line(centre - 8, centre + 8, bit_depth=16, rng=rng, noise=0.002)
    line8 = np.round(line16 / 257.0).astype(np.uint8)
    found16 = measure_targets(line16, 16)
    found8 = measure_targets(line8, 8)
    np.testing.assert_allclose(found16[0], centre, atol=0.1)
    np.testing.assert_allclose(found8[0], found16[0], atol=0.1)
    np.testing.assert_allclose(found8[1], found16[1], atol=0.2)


def test_glints_cut_targets_and_empty_lines_are_not_faces():
    rng = np.random.default_rng(32)
    centre = np.array([500.0, 1500.0, 2500.0])
    line = render_line(centre - 10, centre + 10, rng=rng).astype(np.int64)
    line[3200] = 255  # a one-pixel glint
    line[1000:1004] += 25  # a faint smudge, a tenth of the targets' contrast
    line[-6:] = 200  # a target cut by the end of the line
    found = measure_targets(line.astype(np.uint8), 8)
    np.testing.assert_allclose(found[0], centre, atol=0.1)
    assert measure_targets(np.full(PIXELS, 30, np.uint8), 8)[0].shape == (0,)
    assert measure_targets(render_line(np.array([]), np.array([]), rng=rng), 8)[0].shape == (0,)
    two = measure_targets(line.astype(np.uint8), 8, expected_targets=2)
    assert two[0].shape == (2,)


def test_assignment_with_an_approximate_camera():
    camera = demo_rig()[1]
    z = 1300.0
    u = camera.project(TARGETS_X_MM, z)
    seen = camera.in_view(TARGETS_X_MM, z)
    assert not seen.all(), "the inner camera misses the far targets at 1300 mm"
    detections = np.sort(np.append(u[seen], 1234.5))  # plus a spurious detection
    # nominal mounting: tilt off by 0.8° (about 70 px), centre off by 10 mm, focal off by 2 %
    approximate = camera_from_pose(
        "cam1", PIXELS, camera.centre_mm[0] + 10, 0.0, camera.tilt_deg + 0.8, 5100.0, 2047.5
    )
    which = assign_targets(detections, TARGETS_X_MM, z, approximate)
    expected = np.full(detections.shape, -1)
    for index in np.flatnonzero(seen):
        expected[np.argmin(np.abs(detections - u[index]))] = index
    np.testing.assert_array_equal(which, expected)


def nominal_camera(
    camera: LineScanCamera, tilt_error_deg: float, centre_error_mm: float, focal_error: float
) -> LineScanCamera:
    """The camera as a mounting drawing would give it: pose and focal length a little off."""
    return camera_from_pose(
        camera.name,
        PIXELS,
        camera.centre_mm[0] + centre_error_mm,
        0.0,
        camera.tilt_deg + tilt_error_deg,
        FOCAL_PX * (1 + focal_error),
        2047.5,
    )


@settings(max_examples=60, deadline=None)
@given(
    camera_index=st.integers(0, 3),
    height_mm=st.sampled_from(HEIGHTS_MM.tolist()),
    tilt_error_deg=st.floats(-1.0, 1.0),
    centre_error_mm=st.floats(-10.0, 10.0),
    focal_error=st.floats(-0.01, 0.01),
    spurious_px=st.lists(st.floats(20.0, PIXELS - 20.0), max_size=2),
)
def test_one_line_is_assigned_with_a_nominal_mounting(
    camera_index: int,
    height_mm: float,
    tilt_error_deg: float,
    centre_error_mm: float,
    focal_error: float,
    spurious_px: list[float],
):
    candidates = np.asarray(spurious_px, dtype=np.float64)
    camera = demo_rig()[camera_index]
    u = camera.project(TARGETS_X_MM, height_mm)
    seen = np.flatnonzero(camera.in_view(TARGETS_X_MM, height_mm))
    # Spurious detections between the seen targets: one beyond the ends of the run can stand
    # where a mapping shifted by one target expects a target, which makes a single line
    # ambiguous (found by hypothesis: 836 px, camera 3, 1900 mm, tilt 1°). Calibration never
    # assigns from one line alone: all heights together resolve it (tested below).
    inner = (candidates > u[seen].min()) & (candidates < u[seen].max())
    spurious = [v for v in candidates[inner] if np.min(np.abs(u - v)) > 60.0]
    detections = np.concatenate([u[seen], spurious])
    approximate = nominal_camera(camera, tilt_error_deg, centre_error_mm, focal_error)
    which = assign_targets(detections, TARGETS_X_MM, height_mm, approximate)
    np.testing.assert_array_equal(which, np.concatenate([seen, np.full(len(spurious), -1)]))


@pytest.mark.parametrize("camera_index", range(4))
@pytest.mark.parametrize(
    ("tilt_error_deg", "centre_error_mm", "focal_error"),
    [(2.5, 10.0, 0.02), (-2.5, -10.0, 0.02), (3.0, -5.0, -0.02), (-1.5, 10.0, -0.025)],
)
def test_all_heights_together_resolve_errors_beyond_a_target_spacing(
    camera_index: int, tilt_error_deg: float, centre_error_mm: float, focal_error: float
):
    # a 2.5° tilt error moves the targets by about 220 px: more than their spacing at 2500 mm
    camera = demo_rig()[camera_index]
    approximate = nominal_camera(camera, tilt_error_deg, centre_error_mm, focal_error)
    detections, expected = [], []
    for z in HEIGHTS_MM:
        seen = np.flatnonzero(camera.in_view(TARGETS_X_MM, z))
        u = camera.project(TARGETS_X_MM[seen], z)
        # a spurious detection one spacing beyond the run's start, where a mapping shifted
        # by one target expects a target
        spurious = 2 * u[0] - u[1]
        detections.append(np.append(u, spurious) if 20.0 < spurious < PIXELS - 20.0 else u)
        expected.append(np.append(seen, -1) if 20.0 < spurious < PIXELS - 20.0 else seen)
    mapping = estimate_target_mapping(detections, TARGETS_X_MM, HEIGHTS_MM, approximate)
    for z, found, seen in zip(HEIGHTS_MM, detections, expected, strict=True):
        which = assign_targets(found, TARGETS_X_MM, z, approximate, mapping=mapping)
        np.testing.assert_array_equal(which, seen)


def test_assignment_without_targets_in_front_of_the_camera():
    camera = demo_rig()[0]
    which = assign_targets(np.array([100.0, 200.0]), TARGETS_X_MM, -3000.0, camera)
    np.testing.assert_array_equal(which, [-1, -1])


def test_assignment_by_order_needs_every_target():
    centre = np.array([3000.0, 100.0, 1500.0])
    targets = np.array([0.0, -100.0, 100.0])
    np.testing.assert_array_equal(assign_targets(centre, targets, 1500.0), [2, 1, 0])
    np.testing.assert_array_equal(
        assign_targets(centre, targets, 1500.0, ascending=False), [1, 2, 0]
    )
    with pytest.raises(UserError, match=r"2 targets detected.*3 on the bar"):
        assign_targets(centre[:2], targets, 1500.0)


def test_capture_to_calibration_end_to_end(tmp_path: Path):
    """Render the demo rig's capture, write and read it, measure, calibrate, cross-check."""
    rng = np.random.default_rng(33)
    truth = demo_rig(k1=-0.01)
    path = tmp_path / "capture.h5"
    write_capture(path, render_capture(truth, rng))
    capture = read_capture(path)
    approximate = {c.name: nominal_camera(c, 2.0, 8.0, 0.02) for c in truth}
    measured = measure_capture(capture, approximate)
    calibrated = []
    x_check = np.linspace(-400.0, 400.0, 41)
    z_check = np.linspace(1300.0, 2500.0, 41)[:, np.newaxis]
    for camera in truth:
        targets = measured[camera.name]
        x = TARGETS_X_MM[np.newaxis, :]
        z = HEIGHTS_MM[:, np.newaxis]
        found = np.isfinite(targets.centre_px)
        # every target seen whole is found; none whose face is out of view
        assert np.all(found[camera.in_view(x - 7, z) & camera.in_view(x + 7, z)])
        assert not np.any(found & ~(camera.in_view(x - 3, z) & camera.in_view(x + 3, z)))
        assert targets.spurious == 0
        error = targets.centre_px[found] - camera.project(x, z)[found]
        assert np.max(np.abs(error)) < 0.2
        result = calibrate_camera(camera.name, PIXELS, *targets.points(capture))
        assert result.rms_px < 0.1
        assert result.camera.k1 == pytest.approx(-0.01, abs=0.002)
        calibrated.append(result.camera)
        table = build_resolution_table(
            capture.target_x_mm, capture.heights_mm, targets.width_px, capture.flat_width_mm
        )
        ratio = table.at(x_check, z_check) / camera.resolution_mm_per_px(x_check, z_check)
        seen = camera.in_view(x_check, z_check)
        assert np.sqrt(np.mean((ratio[seen] - 1) ** 2)) < 0.006
        assert np.max(np.abs(ratio[seen] - 1)) < 0.03
    x, z = rng.uniform(-400.0, 400.0, 1000), rng.uniform(1300.0, 2500.0, 1000)
    u = np.stack([camera.project(x, z) for camera in truth], axis=1)
    result = triangulate(calibrated, u)
    assert np.max(np.hypot(result.x_mm - x, result.z_mm - z)) < 1.0
