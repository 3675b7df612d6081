"""The measurement chain: track frame with each scan's own sensors, stagger-angle correction,
the along-track screen of the widths."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest

from catenary.domain import (
    CameraLines,
    ScanBlock,
    VehicleGeometry,
    VehicleSamples,
    WireObservations,
)
from catenary.measurement.chain import MeasurementChain, TrackSamples
from catenary.measurement.wear import (
    DEFAULT_WINDOW_M,
    corrected_wear_width_mm,
    screened_wear_width_mm,
    stagger_angle_rad,
)

GEOMETRY = VehicleGeometry(
    "test", roof_height_mm=3900.0, sensor_height_mm=1100.0, sensor_baseline_mm=1800.0
)
SPACING_M = 0.02
SLOPE_MM_PER_M = 15.0  # the wire's stagger gradient along the track


def run_scans(n: int, seed: int = 1) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    position = np.arange(n) * SPACING_M
    return {
        "position_m": position,
        "left_mm": 10 * np.sin(position / 3.0) + rng.normal(0, 0.1, n),
        "right_mm": -8 * np.sin(position / 4.0),
        "lateral_mm": 5 * np.cos(position / 5.0),
    }


def blocks(scans: dict[str, np.ndarray], size: int, fault_at: slice | None = None):
    n = scans["position_m"].shape[0]
    fault = np.zeros(n, dtype=bool)
    if fault_at is not None:
        fault[fault_at] = True
    for first in range(0, n, size):
        s = slice(first, min(first + size, n))
        yield ScanBlock(
            first_scan=first,
            position_m=scans["position_m"][s],
            time_s=scans["position_m"][s] / 20.0,
            cameras={"cam": CameraLines(np.zeros((s.stop - s.start, 4), np.uint8), 8)},
            vehicle=VehicleSamples(
                time_s=scans["position_m"][s] / 20.0,
                left_mm=scans["left_mm"][s],
                right_mm=scans["right_mm"][s],
                lateral_mm=scans["lateral_mm"][s],
                fault=fault[s],
            ),
        )


def seen_at(
    scan: np.ndarray,
    scans: dict[str, np.ndarray],
    stagger_mm: np.ndarray,
    height_mm: np.ndarray,
    width_mm: np.ndarray,
    cameras: int,
    *,
    uncertain: bool = False,
) -> WireObservations:
    """Wire 0 at these *track-frame* staggers and heights, as the processor gives it: in the
    roof frame of each scan's sensors."""
    from catenary.measurement.vehicle import track_to_roof

    x, z = track_to_roof(
        stagger_mm,
        height_mm,
        scans["left_mm"][scan],
        scans["right_mm"][scan],
        scans["lateral_mm"][scan],
        GEOMETRY,
    )
    m = scan.shape[0]
    return WireObservations(
        scan=scan.astype(np.int64),
        wire=np.zeros(m, np.int64),
        x_roof_mm=x,
        z_roof_mm=z,
        wear_width_mm=width_mm,
        cameras=np.full(m, cameras, np.int64),
        reprojection_rms_px=np.zeros(m),
        selection_uncertain=np.full(m, uncertain),
    )


def observations(scan: np.ndarray, scans: dict[str, np.ndarray], width_mm: float | np.ndarray):
    """One wire whose *track-frame* stagger is a straight line of SLOPE_MM_PER_M; its width
    one value or one per scan of the run."""
    position = scans["position_m"][scan]
    width = np.broadcast_to(width_mm, scans["position_m"].shape)[scan].copy()
    stagger = -200.0 + SLOPE_MM_PER_M * position
    return seen_at(scan, scans, stagger, np.full(scan.shape, 5300.0), width, 4)


def run_chain(
    n: int,
    block: int,
    lag: int,
    fault_at: slice | None = None,
    width_mm: float | np.ndarray = 8.0,
    window_m: float = DEFAULT_WINDOW_M,
) -> TrackSamples:
    """Observations released ``lag`` scans late (a processor's tracking holds them back)."""
    scans = run_scans(n)
    chain = MeasurementChain(GEOMETRY, window_m=window_m)
    out = []
    released = 0
    for b in blocks(scans, block, fault_at):
        upto = max(b.first_scan + b.scans - lag, 0)
        out.append(chain.push(b, observations(np.arange(released, upto), scans, width_mm)))
        released = max(released, upto)
    out.append(chain.finish(observations(np.arange(released, n), scans, width_mm)))
    return TrackSamples.concatenate(out)


def test_every_row_once_in_the_track_frame_with_its_own_scans_sensors():
    n = 2000
    rows = run_chain(n, block=128, lag=300)
    assert np.array_equal(np.sort(rows.scan), np.arange(n))
    scans = run_scans(n)
    position = scans["position_m"][rows.scan]
    np.testing.assert_allclose(rows.stagger_mm, -200.0 + SLOPE_MM_PER_M * position, atol=1e-6)
    np.testing.assert_allclose(rows.height_mm, 5300.0, atol=1e-6)
    np.testing.assert_array_equal(rows.position_m, position)


def test_the_width_is_corrected_by_the_measured_stagger_angle():
    rows = run_chain(2000, block=128, lag=50)
    expected = 8.0 * np.cos(np.arctan(SLOPE_MM_PER_M / 1000.0))
    np.testing.assert_allclose(rows.wear_width_mm, expected, atol=1e-6)
    assert 8.0 - expected > 7e-4  # the correction is there to see


def fitting_widths(n: int) -> np.ndarray:
    """8 mm of wear, noisy, with a dropper clamp's three scans 0.1 mm narrower at 1000."""
    width = 8.0 + np.random.default_rng(2).normal(0.0, 0.012, n)
    width[1000:1003] -= 0.1
    return width


def test_a_fitting_loses_its_width_not_its_rows():
    rows = run_chain(2000, block=128, lag=50, width_mm=fitting_widths(2000))
    assert np.array_equal(np.sort(rows.scan), np.arange(2000))
    screened = np.sort(rows.scan[np.isnan(rows.wear_width_mm)])
    np.testing.assert_array_equal(screened, [1000, 1001, 1002])


def test_block_size_and_release_lag_do_not_change_the_rows():
    a = run_chain(1500, block=100, lag=0, width_mm=fitting_widths(1500))
    b = run_chain(1500, block=512, lag=400, width_mm=fitting_widths(1500))
    order_a, order_b = np.argsort(a.scan), np.argsort(b.scan)
    assert np.isnan(a.wear_width_mm).any()  # the screen is at work
    np.testing.assert_allclose(a.wear_width_mm[order_a], b.wear_width_mm[order_b], atol=1e-9)
    np.testing.assert_allclose(a.stagger_mm[order_a], b.stagger_mm[order_b], atol=1e-9)


@pytest.mark.parametrize("window_m", [DEFAULT_WINDOW_M, 0.2])
def test_the_chain_screens_as_the_whole_run_at_once(window_m: float):
    n = 3000
    width = 8.0 + np.random.default_rng(4).normal(0.0, 0.012, n)
    for first in (99, 510, 1023, 1500, 2047):  # clamps across blocks' and releases' ends
        width[first : first + 3] -= 0.1
    runs = [
        run_chain(n, block=block, lag=lag, width_mm=width, window_m=window_m)
        for block, lag in ((100, 0), (512, 37), (1024, 600))
    ]
    rows = runs[0]
    theta = stagger_angle_rad(rows.position_m, rows.stagger_mm, window_m)
    expected = screened_wear_width_mm(
        rows.position_m, corrected_wear_width_mm(width[rows.scan], theta)
    )
    assert np.count_nonzero(np.isnan(expected)) >= 15
    for got in runs:
        order = np.argsort(got.scan)
        np.testing.assert_allclose(got.wear_width_mm[order], expected[np.argsort(rows.scan)])


def test_a_sensor_fault_flags_its_scans():
    rows = run_chain(1000, block=128, lag=20, fault_at=slice(300, 350))
    flagged = np.sort(rows.scan[rows.vehicle_fault])
    np.testing.assert_array_equal(flagged, np.arange(300, 350))


def test_a_row_released_too_late_is_refused():
    scans = run_scans(30000)
    chain = MeasurementChain(GEOMETRY, history_m=50.0)
    for b in blocks(scans, 1024):
        if b.first_scan > 5000:
            with pytest.raises(ValueError, match="within 50 m"):
                chain.push(b, observations(np.arange(0, 10), scans, 8.0))
            return
        chain.push(b, observations(np.zeros(0, np.int64), scans, 8.0))


def test_a_wire_that_ended_is_given_out_before_the_run_ends():
    scans = run_scans(20000)  # 400 m
    chain = MeasurementChain(GEOMETRY, history_m=50.0)
    given = []
    for b in blocks(scans, 1024):
        scan = np.arange(b.first_scan, b.first_scan + b.scans)
        ended = scan[scans["position_m"][scan] < 100.0]  # the wire leaves the view at 100 m
        given.append(chain.push(b, observations(ended, scans, 8.0)))
    rows = TrackSamples.concatenate(given)
    assert rows.rows == np.count_nonzero(scans["position_m"] < 100.0)
    assert chain.finish(observations(np.zeros(0, np.int64), scans, 8.0)).rows == 0


def messenger(scan: np.ndarray, scans: dict[str, np.ndarray]) -> WireObservations:
    """Rows of the same wire number that the processor could not decide are the contact wire:
    a messenger 1,200 mm above it, 300 mm aside, at another stagger gradient, 3 mm wide."""
    position = scans["position_m"][scan]
    stagger = 100.0 - 40.0 * position
    height = np.full(scan.shape, 6500.0)
    return seen_at(scan, scans, stagger, height, np.full(scan.shape, 3.0), 3, uncertain=True)


def together(a: WireObservations, b: WireObservations) -> WireObservations:
    return WireObservations(
        **{f.name: np.concatenate([getattr(a, f.name), getattr(b, f.name)]) for f in fields(a)}
    )


def test_uncertain_rows_keep_their_flag_and_never_touch_the_wires_angle_or_screen():
    """A messenger's rows interleaved with the contact wire's under one wire number: the
    contact wire's rows come out exactly as without them; the messenger's are flagged, with
    their own position and a width corrected by their own stagger angle."""
    n, lag = 2000, 50
    width = fitting_widths(n)
    scans = run_scans(n)
    chain = MeasurementChain(GEOMETRY)
    out = []
    released = 0
    for b in blocks(scans, 128):
        upto = max(b.first_scan + b.scans - lag, 0)
        scan = np.arange(released, upto)
        unsure = scan[(scan >= 900) & (scan < 1100)]
        out.append(
            chain.push(b, together(observations(scan, scans, width), messenger(unsure, scans)))
        )
        released = max(released, upto)
    scan = np.arange(released, n)
    out.append(chain.finish(observations(scan, scans, width)))
    rows = TrackSamples.concatenate(out)
    plain = run_chain(n, block=128, lag=lag, width_mm=width)
    certain = rows.take(~rows.selection_uncertain)
    assert not plain.selection_uncertain.any()
    for name in ("scan", "stagger_mm", "height_mm", "wear_width_mm", "vehicle_fault"):
        np.testing.assert_allclose(getattr(certain, name), getattr(plain, name), atol=1e-9)
    unsure = rows.take(rows.selection_uncertain)
    np.testing.assert_array_equal(unsure.scan, np.arange(900, 1100))
    np.testing.assert_allclose(unsure.height_mm, 6500.0, atol=1e-6)
    np.testing.assert_allclose(unsure.wear_width_mm, 3.0 * np.cos(np.arctan(0.04)), atol=1e-6)


def test_observations_without_the_flag_are_all_the_contact_wire():
    scans = run_scans(10)
    obs = observations(np.arange(10), scans, 8.0)
    np.testing.assert_array_equal(obs.selection_uncertain, np.zeros(10, dtype=bool))
    with pytest.raises(ValueError, match="selection_uncertain"):
        WireObservations(
            **{f.name: getattr(obs, f.name) for f in fields(obs)}
            | {"selection_uncertain": np.zeros(3, dtype=bool)}
        )
