"""Recorded runs: the run file, its ground truth, the register, streaming and determinism."""

from __future__ import annotations

import csv
import tracemalloc
from pathlib import Path

import h5py
import numpy as np
import pytest

from catenary.errors import UserError
from catenary.measurement.runfile import open_run
from catenary.measurement.sensors import DEFAULT_FILTER_HZ, SENSOR_NAMES, SensorSmoother
from catenary.measurement.vehicle import roof_to_track
from catenary_linescan.simulator import open_simulation, record_run
from catenary_linescan.simulator.rig import SimRig


def settings(rig: SimRig, **extra):
    base = {
        "rig": rig,
        "length_m": 30.0,
        "seed": 5,
        "scan_rate_hz": 500.0,
        "speed_kmh": 60.0,
        "chunk_scans": 128,
        "curve_radius_m": 0.0,
    }
    base.update(extra)
    return base


@pytest.fixture(scope="module")
def recorded(small_rig: SimRig, tmp_path_factory: pytest.TempPathFactory):
    out = tmp_path_factory.mktemp("run") / "sim.h5"
    return record_run(out, settings(small_rig, encoder_scale_error=0.003))


def test_run_opens_with_the_right_header_and_shapes(recorded, small_rig: SimRig) -> None:
    with open_run(recorded.run_path) as run:
        header = run.header
        assert header.scans == recorded.scans > 800
        assert header.scan_rate_hz == 500.0
        assert header.vehicle == small_rig.name and header.direction == "increasing"
        assert header.camera_pixels == {c.name: 1024 for c in small_rig.cameras}
        assert header.camera_bit_depth == {c.name: 8 for c in small_rig.cameras}
        assert run.complete
        total = 0
        for block in run.blocks(300):
            total += block.scans
            for lines in block.cameras.values():
                assert lines.lines.dtype == np.uint8 and lines.lines.shape == (block.scans, 1024)
            assert not block.vehicle.fault.any()
        assert total == header.scans


def test_truth_layout_and_register(recorded) -> None:
    with h5py.File(recorded.truth_path) as truth:
        assert truth.attrs["format"] == "catenary-simulation-truth"
        n = recorded.scans
        m = truth["wires/id"].shape[0]
        assert m == 4 and list(truth["wires/contact"][()]) == [True, False, True, False]
        for name in ("x_roof_mm", "height_mm", "wear_width_mm", "residual_thickness_mm"):
            assert truth[f"wires/{name}"].shape == (n, m)
        assert truth["scans/chainage_m"].shape == (n,)
        for cam in ("cam1", "cam4"):
            assert truth[f"cameras/{cam}/u_px"].shape == (n, m)
            assert truth[f"cameras/{cam}"].attrs["matrix"].shape == (2, 3)
        w0 = truth["wires/wear_width_mm"][()]
        w = truth["wires/wear_width_inplane_mm"][()]
        theta = np.radians(truth["wires/stagger_angle_deg"][()])
        ok = np.isfinite(w0)
        np.testing.assert_allclose(w0[ok], (w * np.cos(theta))[ok])
        masts = [s.decode() for s in truth["masts/mast"][()]]
    with open(recorded.masts_path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0]) == [
        "line",
        "track",
        "mast",
        "chainage_m",
        "wire_type",
        "design_stagger_mm",
    ]
    assert [r["mast"] for r in rows] == masts
    assert all(r["wire_type"] == "CTA120" for r in rows)


def test_vehicle_sensors_in_the_run_reproduce_the_truth(recorded, small_rig: SimRig) -> None:
    """The truth's roof-frame contact points, taken through the run's (noisy, interpolated)
    sensors with the FORMATS.md model, land on the truth's track-frame points."""
    with h5py.File(recorded.truth_path) as truth, open_run(recorded.run_path) as run:
        x = truth["wires/x_roof_mm"][()]
        z = truth["wires/z_roof_mm"][()]
        stagger = truth["wires/stagger_mm"][()]
        height = truth["wires/height_mm"][()]
        blocks = list(run.blocks(10_000))
        left = np.concatenate([b.vehicle.left_mm for b in blocks])[:, None]
        right = np.concatenate([b.vehicle.right_mm for b in blocks])[:, None]
        lateral = np.concatenate([b.vehicle.lateral_mm for b in blocks])[:, None]
        # the exact sensor values (the body pose) give the truth exactly
        sx, sz = roof_to_track(
            x,
            z,
            truth["scans/left_mm"][()][:, None],
            truth["scans/right_mm"][()][:, None],
            truth["scans/lateral_mm"][()][:, None],
            small_rig.vehicle,
        )
        ok = np.isfinite(x)
        np.testing.assert_allclose(sx[ok], stagger[ok], atol=1e-6)
        np.testing.assert_allclose(sz[ok], height[ok], atol=1e-6)
        mx, mz = roof_to_track(x, z, left, right, lateral, small_rig.vehicle)
        # sensor noise 0.3 mm, 4.2-4.4 m from the sensors to the wire over a 1.8 m baseline:
        # 1.0-1.1 mm RMS of stagger from the roll, within a few millimetres
        assert np.abs(mx - stagger)[ok].max() < 5.0
        assert np.abs(mz - height)[ok].max() < 2.0
        # smoothed below 5 Hz as catenary process does: under half that RMS, within 2 mm
        smoother = SensorSmoother(DEFAULT_FILTER_HZ, run.vehicle_interval_s)
        smoothed = list(run.blocks(10_000, smoother=smoother))
        sx, sz = roof_to_track(
            x,
            z,
            *(
                np.concatenate([getattr(b.vehicle, k) for b in smoothed])[:, None]
                for k in SENSOR_NAMES
            ),
            small_rig.vehicle,
        )
        assert np.sqrt(np.mean((sx - stagger)[ok] ** 2)) < 0.5
        assert np.abs(sx - stagger)[ok].max() < 2.0
        assert np.abs(sz - height)[ok].max() < 1.0
        noise = smoother.noise_mm
        assert noise is not None
        np.testing.assert_allclose(noise, 0.3, rtol=0.1)


def test_encoder_error_is_in_the_run(recorded) -> None:
    with h5py.File(recorded.truth_path) as truth, open_run(recorded.run_path) as run:
        position = np.concatenate([b.position_m for b in run.blocks(10_000)])
        distance = truth["scans/distance_m"][()]
        assert truth.attrs["encoder_scale_error"] == 0.003
        assert position[-1] / distance[-1] == pytest.approx(1.003, abs=1e-4)
        header = run.header.start_chainage_m
        assert header - truth.attrs["true_start_chainage_m"] == pytest.approx(
            truth.attrs["start_chainage_error_m"]
        )


def test_same_seed_same_run_and_blocks_do_not_matter(small_rig: SimRig) -> None:
    a = open_simulation(settings(small_rig, length_m=8.0))
    b = open_simulation(settings(small_rig, length_m=8.0))
    c = open_simulation(settings(small_rig, length_m=8.0, seed=6))
    lines_a = np.concatenate([blk.cameras["cam2"].lines for blk in a.blocks(100)])
    lines_b = np.concatenate([blk.cameras["cam2"].lines for blk in b.blocks(77)])
    lines_c = np.concatenate([blk.cameras["cam2"].lines for blk in c.blocks(100)])
    assert np.array_equal(lines_a, lines_b)
    assert not np.array_equal(lines_a, lines_c)
    starts = [blk.first_scan for blk in a.blocks(100)]
    assert starts == list(range(0, a.header.scans, 100))


def test_streaming_memory_does_not_grow_with_the_run(small_rig: SimRig) -> None:
    def peak(length_m: float) -> int:
        stream = open_simulation(settings(small_rig, length_m=length_m, chunk_scans=64))
        tracemalloc.start()
        tracemalloc.reset_peak()
        for _ in stream.blocks(64):
            pass
        _, top = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        return top

    short = peak(6.0)
    long = peak(36.0)  # six times the scans
    assert long < 1.25 * short


def test_sun_blinded_camera_saturates_for_a_stretch(small_rig: SimRig) -> None:
    stream = open_simulation(
        settings(
            small_rig, length_m=30.0, scan_rate_hz=150.0, lighting="day-filter", sun_blind="cam3"
        )
    )
    chunks = list(stream.chunks())
    glare = np.concatenate([c.truth.sun_glare for c in chunks])
    blind = np.concatenate([c.lines["cam3"] for c in chunks])
    other = np.concatenate([c.lines["cam2"] for c in chunks])
    full = glare == 1.0
    assert full.any() and (glare == 0.0).any()
    assert np.all(blind[full] == 255)
    assert np.mean(blind[glare == 0.0] == 255) < 0.01
    assert np.mean(other == 255) < 0.01


def test_partial_sun_glare_saturates_part_of_the_line(small_rig: SimRig) -> None:
    """``sun_blind_strength`` below 1: the halo around the sun saturates part of the line
    and the rest is veiled, not lost."""
    stream = open_simulation(
        settings(
            small_rig,
            length_m=30.0,
            scan_rate_hz=150.0,
            lighting="day-white",
            sun_blind="cam3",
            sun_blind_strength=0.1,
        )
    )
    chunks = list(stream.chunks())
    glare = np.concatenate([c.truth.sun_glare for c in chunks])
    blind = np.concatenate([c.lines["cam3"] for c in chunks])
    assert glare.max() == pytest.approx(0.1)
    saturated = np.mean(blind[glare == glare.max()] == 255)
    assert 0.05 < saturated < 0.7


def test_night_and_day_polarity(small_rig: SimRig) -> None:
    """At night and with the filtered blue strobe the worn face is bright on a dark sky;
    with white light by day the wire is a dark silhouette whose face is brighter than its
    sides."""
    results = {}
    for lighting in ("night", "day-filter", "day-white"):
        stream = open_simulation(
            settings(small_rig, length_m=3.0, lighting=lighting, noise=False, overlap=False)
        )
        chunk = next(stream.chunks())
        cam = "cam3"
        truth = chunk.truth.cameras[cam]
        line = chunk.lines[cam].astype(float)
        row = 10
        face = line[row, round(np.nanmean(truth.u_px[row, 0]))]
        left = truth.left_px[row, 0]
        sky = np.median(line[row])
        results[lighting] = (face, sky)
        if lighting == "day-white":
            silhouette = line[row, round(left) : round(truth.right_px[row, 0])]
            assert silhouette.min() < 0.3 * sky
            assert face > 2.0 * silhouette.min()
        else:
            assert face > 4.0 * sky
    assert results["day-filter"][1] > results["night"][1]
    assert results["day-white"][1] > 5 * results["day-filter"][1]


def test_bad_settings_are_user_errors(small_rig: SimRig, tmp_path: Path) -> None:
    with pytest.raises(UserError, match="no camera 'camX'"):
        open_simulation(settings(small_rig, sun_blind="camX"))
    with pytest.raises(UserError, match="lighting"):
        open_simulation(settings(small_rig, lighting="dusk"))
    with pytest.raises(UserError, match="unknown simulation setting"):
        open_simulation(settings(small_rig, lenght_m=3))
    out = tmp_path / "x.h5"
    out.write_bytes(b"")
    with pytest.raises(UserError, match="already exists"):
        record_run(out, settings(small_rig, length_m=2.0))


def test_faces_in_a_run_are_where_the_truth_says(demo_rig: SimRig) -> None:
    """Through roll, sway, stagger angle and defocus: in a noiseless run the worn faces'
    centres are within 0.3 px of the truth's image of the contact point, and their widths
    within 4 % of the truth's face ends."""
    import dataclasses
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from test_render import face_edges

    rig = dataclasses.replace(demo_rig, cameras=(demo_rig.camera("cam3"),))
    stream = open_simulation(
        {"rig": rig, "length_m": 6.0, "seed": 26, "noise": False, "chunk_scans": 128}
    )
    checked = 0
    for chunk in stream.chunks():
        lines = chunk.lines["cam3"].astype(float)
        truth = chunk.truth
        cam = truth.cameras["cam3"]
        for row in range(0, chunk.scans, 16):
            for m in np.flatnonzero(np.nan_to_num(truth.wear_width_mm[row]) > 4.0):
                a, b = cam.face_left_px[row, m], cam.face_right_px[row, m]
                if not (20 < a < 4070 and 20 < b < 4070):
                    continue
                left, right = face_edges(lines[row], a, b)
                assert 0.5 * (left + right) == pytest.approx(cam.u_px[row, m], abs=0.3)
                assert right - left == pytest.approx(b - a, rel=0.04)
                checked += 1
    assert checked > 10


def test_decreasing_direction_mirrors_the_track_frame(small_rig: SimRig) -> None:
    stream = open_simulation(
        settings(small_rig, length_m=4.0, direction="decreasing", start_chainage_m=15000.0)
    )
    assert stream.header.direction == "decreasing"
    chunk = next(stream.chunks())
    chainage = chunk.truth.chainage_m
    assert chainage[0] == pytest.approx(15000.0) and np.all(np.diff(chainage) < 0)
    line_frame = stream.simulation.scene.sample(chainage)
    ok = chunk.truth.present
    np.testing.assert_allclose(chunk.truth.stagger_mm[ok], -line_frame.stagger_mm[ok])
