"""Ground truth beside a simulated run: ``NAME.truth.h5`` and the mast register CSV.

Layout of ``NAME.truth.h5`` (``N`` scans, ``M`` wires; float64 unless said; NaN where a wire is
absent or a value does not apply; every per-scan dataset chunked along scans):

==============================================  =============================================
``/`` attrs                                     ``format = "catenary-simulation-truth"``,
                                                ``format_version = 1``, ``run_file`` (the run's
                                                file name), ``seed``, ``lighting``,
                                                ``lamp_kind``, ``settings_json`` (every
                                                simulation setting), ``rig_toml`` (the rig
                                                file's text), ``wire_type``, ``wire_height_mm``
                                                (A), ``wire_width_mm`` (B), ``wire_area_mm2``,
                                                ``direction``, ``true_start_chainage_m``,
                                                ``header_start_chainage_m``,
                                                ``start_chainage_error_m``,
                                                ``encoder_scale_error``, ``scan_rate_hz``,
                                                ``curve_radius_m`` (0: straight),
                                                ``curve_start_m``, ``curve_end_m``,
                                                ``turnout_angle_deg`` (0: no turnout),
                                                ``turnout_crossing_m`` (NaN: none), where
                                                the contact wires cross in plan
``/scans/distance_m``                           true distance since the first scan ``[N]``
``/scans/chainage_m``                           true chainage ``[N]``
``/scans/time_s``, ``/scans/position_m``        as in the run (position: the encoder's)
``/scans/speed_m_s``                            true speed ``[N]``
``/scans/roll_deg``                             body roll, positive = left side up ``[N]``
``/scans/lateral_mm``                           body lateral displacement (FORMATS.md) ``[N]``
``/scans/bounce_mm``                            body bounce, ``(left + right) / 2`` ``[N]``
``/scans/left_mm``, ``/scans/right_mm``         noise-free sensor values at the scans ``[N]``
``/scans/sun_glare``                            sun glare on the blinded camera (0-1)
``/wires/id``                                   int ``[M]``: stable wire ids (the column index)
``/wires/name``                                 str ``[M]``: ``CW-A``, ``MW-A``, ``CW-B`` ...
                                                (``CW-T``, ``MW-T``: a turnout's diverging
                                                contact wire and its messenger)
``/wires/contact``                              bool ``[M]``: contact wire (else messenger)
``/wires/partner``                              int ``[M]``: a contact wire's messenger and back
``/wires/present``                              bool ``[N, M]``: the wire exists at the scan
``/wires/running``                              bool ``[N, M]``: a contact wire in running
                                                position (raised < 20 mm)
``/wires/x_roof_mm``, ``/wires/z_roof_mm``      roof frame of the contact point (the face's
                                                centre; a messenger's underside) ``[N, M]``
``/wires/stagger_mm``, ``/wires/height_mm``     the same point in the run's track frame
``/wires/wear_width_mm``                        true face width ``w0`` across the wire
``/wires/wear_width_inplane_mm``                apparent width in the scanning plane
                                                ``w = w0 / cos θ``
``/wires/residual_thickness_mm``                ``(A - R) + sqrt(R² - (w0/2)²)``
``/wires/stagger_angle_deg``                    ``θ``: the wire's angle to the track in plan
``/wires/lift_mm``                              a contact wire's height above its running
                                                position (0 where running)
``/cameras/{name}`` attrs                       ``matrix`` (2x3, normalised, TRUE), ``k1``,
                                                ``pixels``, ``bit_depth``
``/cameras/{name}/u_px``                        image of the contact point ``[N, M]``
``/cameras/{name}/face_left_px``, ``face_right_px``  image of the face's ends ``[N, M]``
``/cameras/{name}/left_px``, ``right_px``       the wire's silhouette ``[N, M]``
``/masts/{line,track,mast,wire_type}``          str ``[K]``: the mast register
``/masts/chainage_m``, ``/masts/design_stagger_mm``, ``/masts/side`` (+1 right)
``/fittings/{kind,wire,chainage_m,y_mm,h_mm}``  droppers, clamps, steady arms, registration
                                                tubes (line frame: ``y`` right of increasing
                                                chainage, ``h`` centre above rail)
==============================================  =============================================

Image positions follow FORMATS.md (pixel ``i`` centred on ``u = i``) and include distortion;
the face's ends in the image are where the face's edges are, before blur.

The mast register is also written as ``NAME.masts.csv`` in the FORMATS.md layout
(``line,track,mast,chainage_m,wire_type,design_stagger_mm``; ``design_stagger_mm`` looking
toward increasing chainage).
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from .simulation import Chunk, Simulation

__all__ = ["TRUTH_FORMAT", "TruthWriter", "truth_path_for", "write_mast_register"]

TRUTH_FORMAT = "catenary-simulation-truth"
TRUTH_FORMAT_VERSION = 1
_SCAN_FIELDS = (
    "distance_m",
    "chainage_m",
    "speed_m_s",
    "roll_deg",
    "lateral_mm",
    "bounce_mm",
    "left_mm",
    "right_mm",
    "sun_glare",
)
_WIRE_FIELDS = (
    "x_roof_mm",
    "z_roof_mm",
    "stagger_mm",
    "height_mm",
    "wear_width_mm",
    "wear_width_inplane_mm",
    "residual_thickness_mm",
    "stagger_angle_deg",
    "lift_mm",
)
_CAMERA_FIELDS = ("u_px", "face_left_px", "face_right_px", "left_px", "right_px")


def truth_path_for(run_path: str | Path) -> Path:
    """``NAME.truth.h5`` beside ``NAME.h5``."""
    path = Path(run_path)
    return path.with_name(path.stem + ".truth.h5")


def masts_path_for(run_path: str | Path) -> Path:
    """``NAME.masts.csv`` beside ``NAME.h5``."""
    path = Path(run_path)
    return path.with_name(path.stem + ".masts.csv")


def write_mast_register(path: str | Path, simulation: Simulation) -> None:
    """The scene's masts as a FORMATS.md mast register CSV."""
    settings = simulation.settings
    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(["line", "track", "mast", "chainage_m", "wire_type", "design_stagger_mm"])
        for mast in simulation.scene.masts:
            writer.writerow(
                [
                    settings.line,
                    settings.track,
                    mast.code,
                    f"{mast.chainage_m:.3f}",
                    mast.wire_type,
                    f"{mast.design_stagger_mm:.1f}",
                ]
            )


def _text(values: list[str]) -> np.ndarray[Any, Any]:
    return np.array(values, dtype=h5py.string_dtype())


class TruthWriter:
    """Write ``NAME.truth.h5`` chunk by chunk (module docstring); a context manager."""

    def __init__(self, path: str | Path, simulation: Simulation, run_file: str = "") -> None:
        self.path = Path(path)
        self.simulation = simulation
        self._file = h5py.File(self.path, "w")
        self._rows = 0
        try:
            self._create(run_file)
        except BaseException:
            self._file.close()
            raise

    def _create(self, run_file: str) -> None:
        sim = self.simulation
        scene = sim.scene
        f = self._file
        dims = scene.wire_type
        radius = 1.0 / scene.curvature_per_m if scene.curvature_per_m else 0.0
        attrs = {
            "format": TRUTH_FORMAT,
            "format_version": np.int64(TRUTH_FORMAT_VERSION),
            "run_file": run_file,
            "seed": np.int64(sim.settings.seed),
            "lighting": sim.settings.lighting,
            "lamp_kind": sim.conditions.lamp_kind,
            "settings_json": json.dumps(sim.settings.as_dict(), default=str),
            "rig_toml": sim.rig.text,
            "wire_type": dims.name,
            "wire_height_mm": dims.height_mm,
            "wire_width_mm": dims.width_mm,
            "wire_area_mm2": dims.area_mm2,
            "direction": sim.settings.direction,
            "true_start_chainage_m": sim.motion.start_chainage_m,
            "header_start_chainage_m": sim.motion.header_start_chainage_m,
            "start_chainage_error_m": sim.motion.start_chainage_error_m,
            "encoder_scale_error": sim.motion.encoder_scale_error,
            "scan_rate_hz": sim.settings.scan_rate_hz,
            "curve_radius_m": radius,
            "curve_start_m": scene.curve_start_m if math.isfinite(scene.curve_start_m) else np.nan,
            "curve_end_m": scene.curve_end_m if math.isfinite(scene.curve_end_m) else np.nan,
            "turnout_angle_deg": scene.turnout.angle_deg if scene.turnout else 0.0,
            "turnout_crossing_m": scene.turnout.crossing_m if scene.turnout else np.nan,
        }
        for key, value in attrs.items():
            f.attrs[key] = value
        wires = scene.wires
        m = len(wires)
        rows = 4096
        for name in (*_SCAN_FIELDS, "time_s", "position_m"):
            f.create_dataset(f"scans/{name}", (0,), "f8", maxshape=(None,), chunks=(rows * 4,))
        g = f.create_group("wires")
        g["id"] = np.array([w.id for w in wires], dtype=np.int64)
        g["name"] = _text([w.name for w in wires])
        g["contact"] = np.array([w.contact for w in wires])
        g["partner"] = np.array([w.partner for w in wires], dtype=np.int64)
        for name in ("present", "running"):
            g.create_dataset(name, (0, m), "?", maxshape=(None, m), chunks=(rows, m))
        for name in _WIRE_FIELDS:
            g.create_dataset(name, (0, m), "f8", maxshape=(None, m), chunks=(rows, m))
        for cam in sim.rig.cameras:
            c = f.create_group(f"cameras/{cam.name}")
            model = sim.optics[cam.name].model.normalised()
            c.attrs["matrix"] = model.matrix
            c.attrs["k1"] = model.k1
            c.attrs["pixels"] = np.int64(cam.pixels)
            c.attrs["bit_depth"] = np.int64(cam.bit_depth)
            for name in _CAMERA_FIELDS:
                c.create_dataset(name, (0, m), "f8", maxshape=(None, m), chunks=(rows, m))
        masts = scene.masts
        g = f.create_group("masts")
        g["line"] = _text([sim.settings.line] * len(masts))
        g["track"] = _text([sim.settings.track] * len(masts))
        g["mast"] = _text([mast.code for mast in masts])
        g["chainage_m"] = np.array([mast.chainage_m for mast in masts])
        g["wire_type"] = _text([mast.wire_type for mast in masts])
        g["design_stagger_mm"] = np.array([mast.design_stagger_mm for mast in masts])
        g["side"] = np.array([mast.side for mast in masts], dtype=np.int64)
        fit = scene.fittings
        g = f.create_group("fittings")
        g["kind"] = _text([str(k) for k in fit.kind])
        g["wire"] = fit.wire.astype(np.int64)
        g["chainage_m"] = fit.chainage_m
        g["y_mm"] = fit.y_mm
        g["h_mm"] = fit.h_mm

    def append(self, chunk: Chunk) -> None:
        """Append a chunk's ground truth."""
        f = self._file
        start = self._rows
        stop = start + chunk.scans
        truth = chunk.truth

        def put(ds: Any, values: np.ndarray[Any, Any]) -> None:
            ds.resize(stop, axis=0)
            ds[start:stop] = values

        for name in _SCAN_FIELDS:
            put(f[f"scans/{name}"], getattr(truth, name))
        put(f["scans/time_s"], chunk.time_s)
        put(f["scans/position_m"], chunk.position_m)
        for name in ("present", "running", *_WIRE_FIELDS):
            put(f[f"wires/{name}"], getattr(truth, name))
        for cam, values in truth.cameras.items():
            for name in _CAMERA_FIELDS:
                put(f[f"cameras/{cam}/{name}"], getattr(values, name))
        self._rows = stop

    def close(self) -> None:
        if self._file:
            self._file.attrs["scans"] = np.int64(self._rows)
            self._file.close()

    def __enter__(self) -> TruthWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
