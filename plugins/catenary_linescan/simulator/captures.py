"""Simulated calibration captures: the paper's resolution calibration tool (figure 8).

A horizontal bar of targets hangs in the scanning plane above the roof: each target is a short
piece of round bar (radius ``target_radius_mm``) lying along the track with a machined flat
bottom face ``flat_width_mm`` wide (the paper: 6.0 mm) at known ``x``; the bar holding them is
black. It is set at several heights, and every camera records one line per height (in a dark
hall, lit by the rig's own lamps), rendered by the same renderer and sensor model as the runs.

The tool is as good as a workshop makes it, not perfect: each target's face centre is off its
nominal ``x`` by ``N(0, target_x_error_mm)`` (machining and mounting) and the bar at each
setting is off its nominal height by ``N(0, height_error_mm)`` (the slider). The capture file
records the NOMINAL positions, as a user's would; the truth records the actual ones.

``write_captures(path, rig)`` writes the capture in the FORMATS.md layout (through
``catenary_linescan.captures.write_capture``) and ``NAME.truth.h5`` beside it:

==========================================  ================================================
``/`` attrs                                 ``format = "catenary-calibration-truth"``,
                                            ``format_version = 1``, ``seed``, ``rig_toml``,
                                            ``flat_width_mm``, ``target_radius_mm``,
                                            ``lighting``, ``capture_file``
``/targets/x_mm`` ``[T]``, ``/heights_mm`` ``[H]``  as in the capture (nominal)
``/actual_x_mm``, ``/actual_z_mm`` ``[H, T]``  where each face centre really was
``/cameras/{name}`` attrs                   ``matrix`` (the TRUE 2x3 matrix, normalised as in
                                            FORMATS.md), ``k1``, ``pixels``, ``bit_depth``,
                                            ``x_mm``, ``z_mm``, ``tilt_deg``, ``focal_px``,
                                            ``principal_point_px``
``/cameras/{name}/u_px`` ``[H, T]``         image of each actual face centre (NaN: out of
                                            view)
``/cameras/{name}/face_left_px``, ``face_right_px`` ``[H, T]``  images of the face's ends
``/cameras/{name}/resolution_mm_per_px`` ``[H, T]``  the model's ``1 / |du/dx|`` there
==========================================  ================================================

Regenerate the shipped demo captures (demo rig, seed 1) with::

    python -m catenary_linescan.simulator.demo_captures

(``catenary simulate RUN.h5 --captures CAPTURES.h5`` writes captures of any rig beside a run,
with the run's seed.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from catenary.arrays import FloatArray
from catenary.domain import CameraLines
from catenary_linescan.captures import CalibrationCapture, write_capture

from .optics import CameraOptics
from .radiometry import MATERIALS, conditions_for
from .render import Layer, Lighting, footprint, render_electrons
from .rig import SimRig
from .sensor import expose, prnu_map
from .shapes import Bar, WireSection

__all__ = [
    "CAPTURE_TRUTH_FORMAT",
    "CaptureTool",
    "CaptureTruth",
    "render_captures",
    "write_captures",
]

CAPTURE_TRUTH_FORMAT = "catenary-calibration-truth"


@dataclass(frozen=True)
class CaptureTool:
    """The calibration tool and how it is used (lengths in mm)."""

    flat_width_mm: float = 6.0
    target_radius_mm: float = 6.45
    target_x_mm: tuple[float, ...] = tuple(float(x) for x in range(-600, 601, 100))
    heights_mm: tuple[float, ...] = tuple(float(z) for z in range(1300, 2501, 100))
    bar_half_length_mm: float = 750.0
    bar_height_mm: float = 30.0
    target_x_error_mm: float = 0.1
    height_error_mm: float = 0.3


@dataclass(frozen=True)
class CaptureTruth:
    """Where each target's face really is in each camera, ``[H, T]`` per camera."""

    actual_x_mm: FloatArray
    actual_z_mm: FloatArray
    u_px: dict[str, FloatArray]
    face_left_px: dict[str, FloatArray]
    face_right_px: dict[str, FloatArray]
    resolution_mm_per_px: dict[str, FloatArray]


def render_captures(
    rig: SimRig,
    tool: CaptureTool | None = None,
    *,
    seed: int = 1,
    noise: bool = True,
    blur: bool = True,
    subsamples: int = 8,
) -> tuple[CalibrationCapture, CaptureTruth]:
    """Render every camera's line at every bar height; returns the capture and its truth."""
    tool = tool or CaptureTool()
    if tool.flat_width_mm >= 2.0 * tool.target_radius_mm:
        raise ValueError("flat face wider than the target")
    xs = np.asarray(tool.target_x_mm, dtype=np.float64)
    heights = np.asarray(tool.heights_mm, dtype=np.float64)
    h = heights.shape[0]
    rows = np.arange(h)
    radius = tool.target_radius_mm
    above = math.sqrt(radius**2 - (tool.flat_width_mm / 2.0) ** 2)
    zeros = np.zeros(h)
    tool_rng = np.random.default_rng([seed, 0x7001])
    actual_z = heights + tool_rng.normal(0.0, tool.height_error_mm, h) if h else heights
    actual_x = xs + tool_rng.normal(0.0, tool.target_x_error_mm, xs.shape[0])
    layers: list[Layer] = []
    for x in actual_x:
        shape = WireSection(
            centre_x_mm=np.full(h, x),
            centre_z_mm=actual_z + above,
            angle_rad=zeros,
            semi_x_mm=np.full(h, radius),
            semi_z_mm=np.full(h, radius),
            face_z_mm=np.full(h, -above),
        )
        layers.append(
            Layer(
                f"target {x:+.0f}", rows, shape, MATERIALS["target_side"], MATERIALS["target_face"]
            )
        )
    bar = Bar(
        centre_x_mm=zeros.copy(),
        centre_z_mm=actual_z + above + radius + 0.5 * tool.bar_height_mm,
        angle_rad=zeros.copy(),
        half_width_mm=np.full(h, tool.bar_half_length_mm),
        half_height_mm=np.full(h, 0.5 * tool.bar_height_mm),
        normal_scale_x=np.ones(h),
        normal_scale_z=np.ones(h),
    )
    layers.append(Layer("bar", rows, bar, MATERIALS["black_bar"]))
    conditions = conditions_for("night", rig.lighting)
    lighting = Lighting(rig.lamps, conditions.lamp_e, rig.beam_sigma_deg, conditions.ambient_e)
    cameras: dict[str, CameraLines] = {}
    xx, zz = np.meshgrid(actual_x, actual_z)
    truth = CaptureTruth(xx, zz, {}, {}, {}, {})
    for number, cam in enumerate(rig.cameras):
        optics = CameraOptics(cam, conditions.wavelength_nm)
        background = np.full((h, cam.pixels), conditions.sky_e, dtype=np.float32)
        electrons = render_electrons(
            optics, layers, background, lighting, subsamples=subsamples, blur=blur
        )
        rng = np.random.default_rng([seed, 0xCA1, number]) if noise else None
        lines = expose(electrons, cam, rng, prnu=prnu_map(cam))
        cameras[cam.name] = CameraLines(lines, cam.bit_depth)
        model = optics.model
        u = model.project(xx, zz)
        inside = model.in_view(xx, zz)
        truth.u_px[cam.name] = np.where(inside, u, np.nan)
        left = np.empty((h, xs.shape[0]))
        right = np.empty((h, xs.shape[0]))
        for t, layer in enumerate(layers[:-1]):
            fp = footprint(optics, layer.shape)
            left[:, t] = fp.face_left
            right[:, t] = fp.face_right
        truth.face_left_px[cam.name] = np.where(inside, left, np.nan)
        truth.face_right_px[cam.name] = np.where(inside, right, np.nan)
        truth.resolution_mm_per_px[cam.name] = model.resolution_mm_per_px(xx, zz)
    capture = CalibrationCapture(tool.flat_width_mm, xs, heights, cameras)
    return capture, truth


def capture_truth_path_for(path: str | Path) -> Path:
    """``NAME.truth.h5`` beside the capture ``NAME.h5``."""
    p = Path(path)
    return p.with_name(p.stem + ".truth.h5")


def write_captures(
    path: str | Path,
    rig: SimRig,
    tool: CaptureTool | None = None,
    *,
    seed: int = 1,
    noise: bool = True,
) -> tuple[Path, Path]:
    """Render and write the capture (FORMATS.md) and its ground truth beside it."""
    tool = tool or CaptureTool()
    capture, truth = render_captures(rig, tool, seed=seed, noise=noise)
    capture_path = Path(path)
    truth_path = capture_truth_path_for(capture_path)
    write_capture(capture_path, capture)
    with h5py.File(truth_path, "w") as f:
        f.attrs["format"] = CAPTURE_TRUTH_FORMAT
        f.attrs["format_version"] = np.int64(1)
        f.attrs["seed"] = np.int64(seed)
        f.attrs["rig_toml"] = rig.text
        f.attrs["flat_width_mm"] = tool.flat_width_mm
        f.attrs["target_radius_mm"] = tool.target_radius_mm
        f.attrs["lighting"] = "night"
        f.attrs["capture_file"] = capture_path.name
        f["targets/x_mm"] = capture.target_x_mm
        f["heights_mm"] = capture.heights_mm
        f["actual_x_mm"] = truth.actual_x_mm
        f["actual_z_mm"] = truth.actual_z_mm
        f.attrs["target_x_error_mm"] = tool.target_x_error_mm
        f.attrs["height_error_mm"] = tool.height_error_mm
        for cam in rig.cameras:
            g = f.create_group(f"cameras/{cam.name}")
            model = cam.model().normalised()
            g.attrs["matrix"] = model.matrix
            g.attrs["k1"] = model.k1
            g.attrs["pixels"] = np.int64(cam.pixels)
            g.attrs["bit_depth"] = np.int64(cam.bit_depth)
            g.attrs["x_mm"] = cam.x_mm
            g.attrs["z_mm"] = cam.z_mm
            g.attrs["tilt_deg"] = cam.tilt_deg
            g.attrs["focal_px"] = cam.focal_px
            g.attrs["principal_point_px"] = cam.principal_point_px
            g["u_px"] = truth.u_px[cam.name]
            g["face_left_px"] = truth.face_left_px[cam.name]
            g["face_right_px"] = truth.face_right_px[cam.name]
            g["resolution_mm_per_px"] = truth.resolution_mm_per_px[cam.name]
    return capture_path, truth_path
