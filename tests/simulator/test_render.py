"""Physical checks of the line renderer against the true camera models."""

from __future__ import annotations

import math

import numpy as np
import pytest

from catenary_linescan.simulator.optics import CameraOptics
from catenary_linescan.simulator.radiometry import MATERIALS, Material, conditions_for
from catenary_linescan.simulator.render import Layer, Lighting, footprint, render_electrons
from catenary_linescan.simulator.rig import SimRig
from catenary_linescan.simulator.shapes import Bar, WireSection

R = 6.45  # CTA120


def worn_wire(x_mm: float, z_mm: float, w0_mm: float, theta_deg: float = 0.0, roll=0.0):
    """A contact wire whose face centre (contact point) is at (x, z) in the roof frame."""
    above = math.sqrt(R * R - (w0_mm / 2) ** 2)
    return WireSection(
        centre_x_mm=np.array([x_mm - above * math.sin(roll)]),
        centre_z_mm=np.array([z_mm + above * math.cos(roll)]),
        angle_rad=np.array([roll]),
        semi_x_mm=np.array([R / math.cos(math.radians(theta_deg))]),
        semi_z_mm=np.array([R]),
        face_z_mm=np.array([-above]),
    )


def night(rig: SimRig) -> Lighting:
    c = conditions_for("night", rig.lighting)
    return Lighting(rig.lamps, c.lamp_e, rig.beam_sigma_deg, c.ambient_e)


def face_edges(line: np.ndarray, guess_left: float, guess_right: float) -> tuple[float, float]:
    """Face edges as the half-level crossings between the face plateau and the sides."""
    i0 = math.floor(guess_left)
    i1 = math.ceil(guess_right)
    plateau = float(np.median(line[i0 + 2 : i1 - 1]))
    side_left = float(line[i0 - 4])
    side_right = float(line[i1 + 4])

    def crossing(level: float, start: int, stop: int, step: int) -> float:
        i = start
        while (line[i] - level) * (line[i + step] - level) > 0:
            i += step
            assert i != stop
        a, b = line[i], line[i + step]
        return i + step * (level - a) / (b - a)

    mid = (i0 + i1) // 2
    left = crossing(0.5 * (plateau + side_left), mid, i0 - 6, -1)
    right = crossing(0.5 * (plateau + side_right), mid, i1 + 6, 1)
    return left, right


@pytest.mark.parametrize("x_mm", [-350.0, 0.0, 350.0])
@pytest.mark.parametrize("z_mm", [1300.0, 1900.0, 2500.0])
def test_face_centre_and_width_where_the_true_camera_says(
    demo_rig: SimRig, x_mm: float, z_mm: float
) -> None:
    """Noiseless render: the face centre within 0.3 px of the projected contact point, and its
    width in pixels w / resolution within 3 % (demo rig, defocus and distortion included)."""
    w0 = 8.0
    wire = worn_wire(x_mm, z_mm, w0)
    lighting = night(demo_rig)
    for cam in demo_rig.cameras:
        optics = CameraOptics(cam, 465.0)
        layer = Layer("cw", np.array([0]), wire, MATERIALS["wire_side"], MATERIALS["worn_face"])
        line = render_electrons(optics, [layer], np.zeros((1, cam.pixels)), lighting)[0]
        line = line / optics.relative_illumination
        fp = footprint(optics, wire)
        left, right = face_edges(line, fp.face_left[0], fp.face_right[0])
        u_true = float(optics.model.project(x_mm, z_mm))
        assert 0.5 * (left + right) == pytest.approx(u_true, abs=0.3), cam.name
        expected = w0 / float(optics.model.resolution_mm_per_px(x_mm, z_mm))
        assert right - left == pytest.approx(expected, rel=0.03), cam.name
        # the face is several times brighter than the round sides where they show
        face = np.median(line[int(left) + 2 : int(right) - 1])
        for start, stop in ((fp.left[0], fp.face_left[0]), (fp.face_right[0], fp.right[0])):
            if stop - start > 6.0:
                assert face > 3.0 * line[round(0.5 * (start + stop))], cam.name


def test_stagger_angle_widens_the_face_in_the_plane(demo_rig: SimRig) -> None:
    cam = demo_rig.cameras[2]
    optics = CameraOptics(cam, 465.0)
    straight = footprint(optics, worn_wire(100.0, 1500.0, 10.0, 0.0))
    oblique = footprint(optics, worn_wire(100.0, 1500.0, 10.0, 20.0))
    ratio = (oblique.face_right - oblique.face_left) / (straight.face_right - straight.face_left)
    assert ratio[0] == pytest.approx(1.0 / math.cos(math.radians(20.0)), rel=1e-3)


@pytest.mark.parametrize("subsamples", [1, 3, 4, 8])
@pytest.mark.parametrize("blur", [False, True])
def test_pixel_integration_conserves_energy(demo_rig: SimRig, subsamples: int, blur: bool) -> None:
    """A shape of uniform radiance on a black sky: the pixel sum is radiance x silhouette."""
    cam = demo_rig.cameras[0]
    optics = CameraOptics(cam, 465.0)
    flat = Material(diffuse=1.0, gloss=0.0, gloss_sigma_deg=10.0)
    uniform = Lighting((), 0.0, 30.0, ambient_e=1000.0)  # ambient only: the same everywhere
    n = 5
    rng = np.random.default_rng(4)
    wire = WireSection(
        centre_x_mm=rng.uniform(-500, 500, n),
        centre_z_mm=rng.uniform(1300, 2500, n),
        angle_rad=rng.uniform(-0.03, 0.03, n),
        semi_x_mm=np.full(n, 7.0),
        semi_z_mm=np.full(n, 6.45),
        face_z_mm=np.full(n, -4.0),
    )
    bar = Bar(
        centre_x_mm=rng.uniform(-300, 300, n),
        centre_z_mm=rng.uniform(1500, 2000, n),
        angle_rad=rng.uniform(-0.2, 0.2, n),
        half_width_mm=np.full(n, 40.0),
        half_height_mm=np.full(n, 5.0),
        normal_scale_x=np.ones(n),
        normal_scale_z=np.ones(n),
    )
    for shape in (wire, bar):
        layer = Layer("x", np.arange(n), shape, flat, flat)
        line = render_electrons(
            optics, [layer], np.zeros((n, cam.pixels)), uniform, subsamples=subsamples, blur=blur
        )
        total = (line / optics.relative_illumination).sum(axis=1)
        fp = footprint(optics, shape)
        np.testing.assert_allclose(total, 1000.0 * (fp.right - fp.left), rtol=2e-5)


def test_nearer_object_hides_what_is_behind(demo_rig: SimRig) -> None:
    """A contact wire in front of a messenger: the messenger does not show through it."""
    cam = demo_rig.cameras[1]
    optics = CameraOptics(cam, 465.0)
    lighting = night(demo_rig)
    wire = worn_wire(0.0, 1400.0, 6.0)
    centre = optics.centre_mm
    # a messenger on the same ray, 1.5 m further
    direction = np.array([0.0 - centre[0], 1400.0 - centre[1]])
    direction /= np.linalg.norm(direction)
    far = centre + direction * (np.linalg.norm([0.0 - centre[0], 1400.0 - centre[1]]) + 1500)
    messenger = WireSection(
        np.array([far[0]]),
        np.array([far[1]]),
        np.zeros(1),
        np.full(1, 7.0),
        np.full(1, 7.0),
        np.full(1, -7.0),
    )
    rows = np.array([0])
    cw = Layer("cw", rows, wire, MATERIALS["wire_side"], MATERIALS["worn_face"])
    mw = Layer("mw", rows, messenger, Material(5.0, 0.0, 30.0))  # a very bright messenger
    both = render_electrons(optics, [cw, mw], np.zeros((1, cam.pixels)), lighting, blur=False)
    alone = render_electrons(optics, [cw], np.zeros((1, cam.pixels)), lighting, blur=False)
    fp = footprint(optics, wire)
    inside = slice(int(fp.left[0]) + 1, int(fp.right[0]))
    np.testing.assert_allclose(both[0, inside], alone[0, inside], rtol=1e-6)


@pytest.mark.parametrize("w0_mm", [1.5, 4.0, 10.0])
def test_face_alone_renders_exactly_where_and_as_wide_as_it_is(
    demo_rig: SimRig, w0_mm: float
) -> None:
    """A uniformly bright face on black sides: the blurred line's centroid is the face
    interval's centre within 0.005 px and its energy radiance x face width, for every camera
    (defocus, distortion and sub-pixel faces included)."""
    black = Material(diffuse=0.0, gloss=0.0, gloss_sigma_deg=10.0)
    white = Material(diffuse=1.0, gloss=0.0, gloss_sigma_deg=10.0)
    uniform = Lighting((), 0.0, 30.0, ambient_e=1000.0)
    for x_mm, z_mm in ((-400.0, 1300.0), (150.0, 2100.0), (500.0, 2500.0)):
        wire = worn_wire(x_mm, z_mm, w0_mm, theta_deg=1.5, roll=0.01)
        for cam in demo_rig.cameras:
            optics = CameraOptics(cam, 465.0)
            layer = Layer("cw", np.array([0]), wire, black, white)
            line = render_electrons(optics, [layer], np.zeros((1, cam.pixels)), uniform)[0]
            line = line / optics.relative_illumination
            fp = footprint(optics, wire)
            u = np.arange(cam.pixels)
            assert line.sum() == pytest.approx(
                1000.0 * (fp.face_right[0] - fp.face_left[0]), rel=1e-4
            )
            centroid = float((u * line).sum() / line.sum())
            assert centroid == pytest.approx(0.5 * (fp.face_left[0] + fp.face_right[0]), abs=0.005)
