"""Turnouts (a diverging contact wire crossing the main one), low and high system heights, and
the scene parameters' admitted ranges."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from catenary.errors import UserError
from catenary_linescan.commands import simulate
from catenary_linescan.simulator.rig import SimRig
from catenary_linescan.simulator.scene import (
    SHORTEST_DROPPER_MM,
    Scene,
    SceneParams,
    generate_scene,
)
from catenary_linescan.simulator.settings import parse_settings
from catenary_linescan.simulator.simulation import RUNNING_LIFT_MM, Simulation

LENGTH_M = 150.0
START_M = SceneParams().start_chainage_m
CAMERA_VIEW_MM = 600.0  # every demo camera sees x = -600..600 mm at every height


def turnout_scene(angle_deg: float, seed: int, **params: Any) -> Scene:
    return generate_scene(
        SceneParams(length_m=LENGTH_M, overlap=False, turnout_angle_deg=angle_deg, **params), seed
    )


def crossings(chainage: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Chainages where ``a - b`` changes sign between samples (linear interpolation)."""
    d = a - b
    k = np.flatnonzero(np.isfinite(d[:-1]) & np.isfinite(d[1:]) & (d[:-1] * d[1:] <= 0.0))
    return chainage[k] - d[k] * (chainage[k + 1] - chainage[k]) / (d[k + 1] - d[k])


@pytest.mark.parametrize("angle_deg", [2.0, 6.0, 10.0])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_contact_wires_cross_in_plan_at_the_angle_in_view(angle_deg: float, seed: int) -> None:
    scene = turnout_scene(angle_deg, seed)
    turnout = scene.turnout
    assert turnout is not None
    assert scene.contact_ids == [turnout.main, turnout.diverging]
    m, d = turnout.main, turnout.diverging
    c = np.arange(START_M, START_M + LENGTH_M, 0.005)
    s = scene.sample(c)
    y = np.where(s.present, s.stagger_mm, np.nan)
    found = crossings(c, y[:, d], y[:, m])
    assert found.shape[0] == 1  # they cross once, near mid-run, within the cameras' view
    cross = float(found[0])
    assert abs(cross - (START_M + 0.5 * LENGTH_M)) <= 0.2 * LENGTH_M
    assert abs(np.interp(cross, c, y[:, m])) < CAMERA_VIEW_MM - 200.0
    # the angle in plan from the sampled staggers, over 0.5 m each side of the crossing
    near = np.abs(c - cross) < 0.5
    slopes = [np.polyfit(c[near], y[near, j], 1)[0] / 1000.0 for j in (m, d)]
    measured = math.degrees(abs(math.atan(slopes[1]) - math.atan(slopes[0])))
    assert measured == pytest.approx(angle_deg, abs=0.01)
    # at one height where they cross, and both running there
    h = [np.interp(cross, c, s.height_mm[:, j]) for j in (m, d)]
    assert h[1] == pytest.approx(h[0], abs=1.0)
    lift = np.interp(cross, c, s.lift_mm[:, d])
    assert lift < 1.0
    # the diverging wire comes into view from one side and leaves it on the other
    whole = np.linspace(scene.start_m, scene.end_m, 200001)
    w = scene.sample(whole)
    yd = np.where(w.present[:, d], w.stagger_mm[:, d], np.nan)
    side = turnout.side
    assert np.nanmax(-side * yd[whole < cross]) > CAMERA_VIEW_MM
    assert np.nanmax(side * yd[whole > cross]) > CAMERA_VIEW_MM


def test_a_turnout_leaves_the_rest_of_the_line_as_the_seed_made_it() -> None:
    plain = generate_scene(SceneParams(length_m=LENGTH_M, overlap=False), 5)
    scene = turnout_scene(4.0, 5)
    assert scene.masts == plain.masts
    assert plain.turnout is None and len(scene.wires) == len(plain.wires) + 2
    main, plain_main = scene.wires[0], plain.wires[0]
    # the same wires, the main one with one more wear hot spot: the crossing
    for a, b in zip(scene.wires[:2], plain.wires, strict=True):
        for f in dataclasses.fields(a):
            if f.name != "wear_spots":
                assert np.array_equal(
                    np.asarray(getattr(a, f.name)), np.asarray(getattr(b, f.name))
                )
    np.testing.assert_array_equal(main.wear_spots[:-1], plain_main.wear_spots)
    assert main.wear_spots[-1, 0] == scene.turnout.crossing_m
    # every fitting of the plain line is there, plus the turnout's own
    fit, plain_fit = scene.fittings, plain.fittings
    own = (fit.wire == scene.turnout.diverging) | np.isin(
        fit.kind, ["crossing_pipe", "crossing_clamp"]
    )
    assert np.array_equal(fit.chainage_m[~own], plain_fit.chainage_m)
    assert np.array_equal(fit.kind[~own], plain_fit.kind)
    kinds = set(fit.kind[own].tolist())
    assert {"dropper", "dropper_clamp", "crossing_pipe", "crossing_clamp"} <= kinds


@pytest.mark.parametrize("angle_deg", [2.0, 10.0])
def test_droppers_of_both_wires_hang_from_their_own_messengers(angle_deg: float) -> None:
    scene = turnout_scene(angle_deg, 7)
    dims = scene.wire_type
    fit = scene.fittings
    for contact in scene.contact_ids:
        messenger = scene.wires[contact].partner
        at = fit.kind == "dropper"
        at &= fit.wire == contact
        c = fit.chainage_m[at]
        assert c.shape[0] >= 5
        s = scene.sample(c)
        np.testing.assert_allclose(fit.y_mm[at], s.stagger_mm[:, contact], atol=1e-6)
        top = s.height_mm[:, contact] + dims.height_mm
        np.testing.assert_allclose(
            fit.h_mm[at] + fit.half_height_mm[at], s.height_mm[:, messenger], atol=1e-6
        )
        np.testing.assert_allclose(fit.h_mm[at] - fit.half_height_mm[at], top, atol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize(("angle_deg", "seed"), [(2.0, 11), (6.0, 12), (10.0, 13)])
def test_the_truth_runs_the_wire_the_pantograph_touches(
    small_rig: SimRig, angle_deg: float, seed: int
) -> None:
    """In the truth the main wire runs throughout; the diverging wire runs where it is level
    with it (within 20 mm) and within the cameras' view: before, at and just after the
    crossing, never where it has risen or left the view."""
    settings = parse_settings(
        {
            "rig": small_rig,
            "length_m": 60.0,
            "seed": seed,
            "overlap": False,
            "turnout_angle_deg": angle_deg,
            "scan_rate_hz": 500.0,
            "noise": False,
        }
    )
    sim = Simulation(settings)
    turnout = sim.scene.turnout
    assert turnout is not None
    m, d = turnout.main, turnout.diverging
    parts: dict[str, list[np.ndarray]] = {}
    for chunk in sim.chunks():
        for name in ("chainage_m", "present", "running", "stagger_mm", "height_mm", "x_roof_mm"):
            parts.setdefault(name, []).append(getattr(chunk.truth, name))
    t = {k: np.concatenate(v) for k, v in parts.items()}
    c = t["chainage_m"]
    assert t["running"][:, m].all()
    cross = float(crossings(c, t["stagger_mm"][:, d], t["stagger_mm"][:, m])[0])
    assert cross == pytest.approx(turnout.crossing_m, abs=0.01)
    running = t["running"][:, d]
    present = t["present"][:, d]
    above = t["height_mm"][:, d] - t["height_mm"][:, m]
    # at the crossing, just before and just after it: both wires run, at one height
    at = np.abs(c - cross) < 0.05
    assert at.any() and running[at].all()
    assert np.abs(above[at]).max() < 1.0
    assert running[(c < cross - 0.5) & (c > cross - 1.0)].all()
    assert running[(c > cross) & (c < cross + 0.2)].all()
    # where it runs it is level with the main wire and in view; elsewhere it is raised
    assert np.all(above[running] < RUNNING_LIFT_MM) and np.all(above[running] > -0.5)
    assert np.all(np.abs(t["x_roof_mm"][running, d]) < CAMERA_VIEW_MM)
    assert np.all(above[present & ~running] >= RUNNING_LIFT_MM - 0.5)
    # and the run sees it raised on both sides of its running stretch
    assert (present & ~running & (c < cross)).any() and (present & ~running & (c > cross)).any()


@pytest.mark.parametrize("system_mm", [300.0, 1600.0])
@pytest.mark.parametrize(
    "extra", [{"overlap": True}, {"overlap": False, "turnout_angle_deg": 5.0}], ids=str
)
def test_system_heights_300_to_1600_keep_the_messenger_above_its_contact_wire(
    system_mm: float, extra: dict[str, Any]
) -> None:
    for seed in (1, 2, 3):
        scene = generate_scene(
            SceneParams(length_m=300.0, system_height_mm=(system_mm, system_mm), **extra), seed
        )
        dims = scene.wire_type
        c = np.linspace(scene.start_m, scene.end_m, 100001)
        s = scene.sample(c)
        shortest = min(400.0, max(SHORTEST_DROPPER_MM, system_mm - 700.0))
        for contact in scene.contact_ids:
            wire = scene.wires[contact]
            messenger = wire.partner
            both = s.present[:, contact] & s.present[:, messenger]
            gap = s.height_mm[both, messenger] - (s.height_mm[both, contact] + dims.height_mm)
            assert gap.min() >= shortest - 1e-6
            assert gap.max() <= system_mm + 1e-6
            # the system height itself at the supports
            at = scene.sample(wire.support_m)
            system = at.height_mm[:, messenger] - at.height_mm[:, contact] - dims.height_mm
            np.testing.assert_allclose(system, system_mm, atol=1e-6)


def test_narrow_contact_height_ranges_generate_within_them() -> None:
    for low, high in ((1400.0, 1500.0), (1450.0, 1450.0), (2480.0, 2500.0)):
        scene = generate_scene(
            SceneParams(contact_height_above_roof_mm=(low, high), overlap=False), seed=3
        )
        masts = np.array([m.chainage_m for m in scene.masts])
        above = scene.sample(masts).height_mm[:, 0] - scene.params.roof_height_mm
        assert above.min() >= low - 1e-9 and above.max() <= high + 1e-9


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("contact_height_above_roof_mm", (1500.0, 1400.0)),
        ("contact_height_above_roof_mm", (700.0, 1400.0)),
        ("system_height_mm", (200.0, 400.0)),
        ("system_height_mm", (1600.0, 1900.0)),
        ("span_m", (10.0, 40.0)),
        ("stagger_mm", (300.0, 200.0)),
        ("curve_stagger_mm", (0.0, 700.0)),
        ("dropper_spacing_m", (1.0, 5.0)),
        ("wear_base_mm", (-1.0, 2.0)),
        ("wear_base_mm", (1.0,)),
        ("roof_height_mm", 900.0),
        ("curve_radius_m", 100.0),
        ("length_m", 0.0),
        ("turnout_angle_deg", 1.0),
        ("turnout_angle_deg", 11.0),
        ("turnout_angle_deg", "5"),
    ],
)
def test_scene_parameters_outside_their_ranges_are_one_line_errors(name: str, value: Any) -> None:
    params = SceneParams(overlap=name != "turnout_angle_deg", **{name: value})
    with pytest.raises(UserError, match=f"scene parameter {name} = ") as error:
        generate_scene(params, seed=1)
    assert "\n" not in str(error.value)


def test_a_turnout_with_an_overlap_is_refused() -> None:
    with pytest.raises(UserError, match=r"turnout_angle_deg = 5\.0: expected overlap false"):
        generate_scene(SceneParams(turnout_angle_deg=5.0), seed=1)


@pytest.mark.parametrize("value", [1, 11, 1.99, "5", True])
def test_bad_turnout_angle_settings_are_user_errors(value: Any) -> None:
    with pytest.raises(UserError, match="turnout_angle_deg"):
        parse_settings({"turnout_angle_deg": value, "overlap": False})


def test_turnout_settings_reach_the_scene() -> None:
    settings = parse_settings({"turnout_angle_deg": 3, "overlap": False, "length_m": 80.0})
    assert settings.turnout_angle_deg == 3.0
    assert settings.scene_params().turnout_angle_deg == 3.0
    with pytest.raises(UserError, match="overlap false"):
        parse_settings({"turnout_angle_deg": 3})


def test_simulate_turnout_option(tmp_path: Path, small_rig_file: Path) -> None:
    runner = CliRunner()
    args = [str(tmp_path / "a.h5"), "--rig", str(small_rig_file), "--length-m", "4"]
    result = runner.invoke(simulate, [*args, "--no-overlap", "--turnout-angle-deg", "12"])
    assert result.exit_code != 0 and "turnout_angle_deg = 12.0" in result.output
    assert len(result.output.strip().splitlines()) == 1
    result = runner.invoke(simulate, [*args, "--turnout-angle-deg", "4"])
    assert result.exit_code != 0 and "overlap false" in result.output
    result = runner.invoke(
        simulate, [*args, "--scan-rate-hz", "200", "--no-overlap", "--turnout-angle-deg", "4"]
    )
    assert result.exit_code == 0, result.output
    with h5py.File(tmp_path / "a.truth.h5") as truth:
        names = [n.decode() for n in truth["wires/name"][:]]
        assert names == ["CW-A", "MW-A", "CW-T", "MW-T"]
        assert json.loads(truth.attrs["settings_json"])["turnout_angle_deg"] == 4.0
        assert truth.attrs["turnout_angle_deg"] == 4.0
        assert 12000.0 < truth.attrs["turnout_crossing_m"] < 12004.0
