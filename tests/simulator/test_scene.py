"""The scene generator: the line's geometry stays within the field's figures."""

from __future__ import annotations

import math

import numpy as np
import pytest

from catenary.errors import UserError
from catenary.wiretype import residual_thickness_mm
from catenary_linescan.simulator.scene import SceneParams, generate_scene, wire_type_dims
from catenary_linescan.simulator.settings import parse_settings

ROOF = 3900.0


@pytest.fixture(scope="module", params=[1, 2, 3])
def scene(request):
    return generate_scene(SceneParams(length_m=600.0, roof_height_mm=ROOF), seed=request.param)


def test_masts_spans_and_register(scene) -> None:
    chainage = np.array([m.chainage_m for m in scene.masts])
    spans = np.diff(chainage)
    assert np.all(spans <= 65.0 + 1e-9) and np.all(spans >= 30.0)
    # straight spans are 40-65 m, but the one that ends where a curve begins may be shorter
    straight = spans[chainage[1:] < scene.curve_start_m - 1e-6]
    assert np.all(straight >= 40.0 - 1e-9)
    assert chainage[0] <= 12000.0 - 100.0 and chainage[-1] >= 12600.0 + 100.0
    codes = [m.code for m in scene.masts]
    assert len(set(codes)) == len(codes) and all("/" in c for c in codes)
    assert all(abs(m.design_stagger_mm) <= 400.0 for m in scene.masts)


def test_stagger_height_and_system_height(scene) -> None:
    c = np.linspace(12000.0, 12600.0, 6001)
    s = scene.sample(c)
    for wire in scene.wires:
        m = wire.id
        run = s.present[:, m] & (s.lift_mm[:, m] < 1.0)
        if wire.contact:
            assert np.abs(s.stagger_mm[run, m]).max() <= 400.0 + 1e-6
            above_roof = s.height_mm[run, m] - ROOF
            assert above_roof.min() >= 1300.0 - 80.0 and above_roof.max() <= 2500.0
            # the wire bows by a few millimetres between its hanging points
            assert np.all(np.isfinite(s.height_mm[s.present[:, m], m]))
    a = scene.wires[0]
    mw = scene.wires[1]
    support = a.support_m[a.registered]
    _, _, h_cw, _, _ = a.evaluate(support)
    _, _, h_mw, _, _ = mw.evaluate(support)
    system = h_mw - h_cw - scene.wire_type.height_mm
    assert system.min() >= 1100.0 - 1e-6 and system.max() <= 1800.0 + 1e-6


def test_zigzag_on_straight_track(scene) -> None:
    """Consecutive registrations alternate sides (the overlap's middle mast excepted)."""
    masts = scene.masts
    skip = set(scene.overlap_masts[1:2])
    straight = [
        i for i, m in enumerate(masts) if m.chainage_m < scene.curve_start_m - 1.0 and i not in skip
    ]
    for i in straight:
        assert 200.0 <= abs(masts[i].design_stagger_mm) <= 400.0
        if i - 1 in straight:
            assert np.sign(masts[i].design_stagger_mm) != np.sign(masts[i - 1].design_stagger_mm)


def test_droppers_every_5_to_10_m_and_arms_at_registrations(scene) -> None:
    fit = scene.fittings
    wire = scene.wires[0]
    droppers = np.sort(fit.chainage_m[(fit.kind == "dropper") & (fit.wire == 0)])
    for c0, c1 in zip(wire.support_m[:-1], wire.support_m[1:], strict=True):
        inside = droppers[(droppers > c0) & (droppers < c1)]
        gaps = np.diff(np.concatenate([[c0], inside, [c1]]))
        assert gaps.max() <= 10.0 + 1e-9 and gaps[1:-1].min() >= 5.0 - 1e-9
    arms = fit.chainage_m[(fit.kind == "steady_arm") & (fit.wire == 0)]
    np.testing.assert_allclose(np.sort(arms), wire.support_m[wire.registered])


def test_curve_gives_offset_arcs() -> None:
    scene = generate_scene(
        SceneParams(length_m=600.0, curve_radius_m=900.0, curve_direction=1, overlap=False),
        seed=4,
    )
    wire = scene.wires[0]
    curved = np.flatnonzero(wire.curvature_per_m != 0.0)
    assert curved.size >= 3
    k = curved[1]
    c0, c1 = wire.support_m[k], wire.support_m[k + 1]
    length = c1 - c0
    mid = 0.5 * (c0 + c1)
    _, y, _, slope, _ = wire.evaluate(np.array([c0, mid, c1]))
    # registrations on the outside (left of a right-hand curve), the chord bows inward
    assert y[0] < 0 and y[2] < 0
    assert y[1] - 0.5 * (y[0] + y[2]) == pytest.approx(1000.0 * length**2 / (8 * 900.0))
    # the stagger angle is largest at the registration points: sin θ ~ 0.02 (the paper)
    theta = np.degrees(np.arctan(np.abs(slope) / 1000.0))
    assert theta[0] > theta[1] and 0.5 < theta[0] < 2.5


def test_overlap_two_contact_wires_raised_wire_unworn() -> None:
    scene = generate_scene(SceneParams(length_m=400.0, overlap=True, curve_radius_m=0.0), seed=9)
    assert len(scene.contact_ids) == 2 and len(scene.wires) == 4
    j0, j1, j2 = scene.overlap_masts
    c = np.linspace(scene.masts[j0].chainage_m, scene.masts[j2].chainage_m, 2001)
    s = scene.sample(c)
    assert s.present[:, 0].all() and s.present[:, 2].all()
    # at the middle mast both run at the same height, 200 mm apart
    at = scene.sample(np.array([scene.masts[j1].chainage_m]))
    assert at.height_mm[0, 0] == pytest.approx(at.height_mm[0, 2], abs=1e-6)
    assert abs(at.stagger_mm[0, 0] - at.stagger_mm[0, 2]) == pytest.approx(200.0)
    assert at.lift_mm[0, 0] == 0.0 and at.lift_mm[0, 2] == 0.0
    # the ending wire rises out of contact toward the next mast and is not worn there
    end = c > scene.masts[j2].chainage_m - 5.0
    assert np.all(s.lift_mm[end, 0] > 250.0) and np.all(s.wear_width_mm[end, 0] == 0.0)
    assert np.all(s.wear_width_mm[:, 2][c < scene.masts[j0].chainage_m + 5.0] == 0.0)


def test_wear_varies_smoothly_within_limits_with_hot_spots(scene) -> None:
    c = np.linspace(12000.0, 12600.0, 60001)
    s = scene.sample(c)
    wear = s.wear_width_mm[:, 0][s.present[:, 0]]
    assert wear.min() >= 0.0 and wear.max() <= 12.0
    assert np.abs(np.diff(wear)).max() < 0.05  # smooth over 1 cm
    # residual thickness from the profile stays meaningful
    dims = scene.wire_type
    h = residual_thickness_mm(wear, dims.height_mm, dims.width_mm)
    assert h.min() > dims.height_mm - dims.radius_mm
    wire = scene.wires[0]
    spots = wire.wear_spots
    assert spots.shape[0] >= 5  # at every running registration point (and the overlap)


def test_wire_types_come_from_the_plugin() -> None:
    assert wire_type_dims("CTA120").width_mm == pytest.approx(12.90)
    assert wire_type_dims("AC-100").width_mm == pytest.approx(12.00)
    with pytest.raises(UserError, match="unknown wire type"):
        wire_type_dims("XYZ")
    scene = generate_scene(SceneParams(length_m=300.0, wire_type="AC-100"), seed=1)
    assert scene.wires[0].radius_mm == pytest.approx(6.0)
    assert math.isclose(scene.wires[0].max_wear_mm, min(12.0, 0.93 * 12.0))


@pytest.mark.parametrize("direction", ["increasing", "decreasing"])
def test_the_scene_covers_the_run_whichever_way_it_runs(direction: str) -> None:
    settings = parse_settings({"length_m": 1000.0, "direction": direction, "seed": 4})
    scene = generate_scene(settings.scene_params(), settings.seed)
    masts = np.array([m.chainage_m for m in scene.masts])
    step = 1000.0 if direction == "increasing" else -1000.0
    low, high = sorted((settings.start_chainage_m, settings.start_chainage_m + step))
    assert masts.min() < low and masts.max() > high
