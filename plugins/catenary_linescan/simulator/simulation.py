"""The simulation engine: a run rendered chunk by chunk, with its ground truth.

For every chunk of scans (``chunk_scans``, fixed: the results do not depend on how a consumer
blocks the run) it

1. takes the scans' times, true distances and chainages, and the encoder's positions
   (:class:`.motion.Motion`);
2. takes the car body's true pose and places every object of the scene, given in the track
   frame, in the roof frame with ``catenary.measurement.vehicle.track_to_roof`` (FORMATS.md model);
3. builds the cross-sections the scanning plane cuts: contact wires (round, with their worn
   face, widened by ``1/cos θ`` for the stagger angle), messengers, and the fittings the
   plane cuts in these scans (droppers, clamps, steady arms, registration tubes);
4. renders every camera (:mod:`.render`), adds sun glare to a blinded camera, and exposes the
   sensor (:mod:`.sensor`) with noise drawn per chunk and camera from the seed;
5. collects the ground truth (:class:`ChunkTruth`) and the displacement sensor samples that
   fall in the chunk.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from catenary.arrays import BoolArray, FloatArray, UInt8Array, UInt16Array
from catenary.domain import RunHeader, VehicleSamples
from catenary.measurement.runfile import DEFAULT_MAX_GAP_FACTOR
from catenary.measurement.sensors import DEFAULT_FILTER_HZ, SensorSmoother, SensorStream
from catenary.measurement.vehicle import track_to_roof

from .motion import Motion, SensorSamples
from .optics import CameraOptics
from .radiometry import MATERIALS, Sky, conditions_for, sun_glare_e
from .render import Layer, Lighting, footprint, render_electrons, sky_e
from .scene import Scene, generate_scene
from .sensor import expose, prnu_map
from .settings import SimulationSettings
from .shapes import Bar, WireSection

__all__ = ["CameraTruth", "Chunk", "ChunkTruth", "Simulation"]

_FITTING_MATERIAL = {
    "dropper": "dropper",
    "dropper_clamp": "clamp",
    "steady_arm": "arm",
    "registration_clamp": "clamp",
    "registration_tube": "tube",
}
RUNNING_LIFT_MM = 20.0
"""A contact wire is "running" (in contact with the pantograph) where it is raised less than
this above its running position."""


@dataclass(frozen=True)
class CameraTruth:
    """Where each wire falls in one camera, ``[n, M]`` each [px] (NaN: absent, no face)."""

    u_px: FloatArray
    face_left_px: FloatArray
    face_right_px: FloatArray
    left_px: FloatArray
    right_px: FloatArray


@dataclass(frozen=True)
class ChunkTruth:
    """Ground truth of a chunk of ``n`` scans and ``M`` wires (see the README for units)."""

    distance_m: FloatArray
    chainage_m: FloatArray
    speed_m_s: FloatArray
    roll_deg: FloatArray
    lateral_mm: FloatArray
    bounce_mm: FloatArray
    left_mm: FloatArray
    right_mm: FloatArray
    sun_glare: FloatArray
    present: BoolArray
    running: BoolArray
    x_roof_mm: FloatArray
    z_roof_mm: FloatArray
    stagger_mm: FloatArray
    height_mm: FloatArray
    wear_width_mm: FloatArray
    wear_width_inplane_mm: FloatArray
    residual_thickness_mm: FloatArray
    stagger_angle_deg: FloatArray
    lift_mm: FloatArray
    cameras: dict[str, CameraTruth]


@dataclass(frozen=True)
class Chunk:
    """One rendered chunk: what a recording gets, the sensors, and the ground truth."""

    index: int
    first_scan: int
    time_s: FloatArray
    position_m: FloatArray
    lines: dict[str, UInt8Array | UInt16Array]
    sensors: SensorSamples  # the samples this chunk contributes to a recording
    vehicle: VehicleSamples  # the noisy sensors interpolated to the scan times
    truth: ChunkTruth

    @property
    def scans(self) -> int:
        return int(self.time_s.shape[0])


class Simulation:
    """A simulated run: scene, motion, rig and lighting from validated settings."""

    def __init__(self, settings: SimulationSettings) -> None:
        self.settings = settings
        self.rig = settings.rig
        self.geometry = self.rig.vehicle
        # the scene from its own seed when given: the same line under different motion and noise
        self.scene: Scene = generate_scene(settings.scene_params(), settings.scene_rng_seed)
        self.motion = Motion(
            settings.motion_params(),
            settings.seed,
            settings.length_m,
            settings.start_chainage_m,
            self.geometry,
            curve=(self.scene.curve_start_m, self.scene.curve_end_m, self.scene.curvature_per_m),
        )
        self.conditions = conditions_for(settings.lighting, self.rig.lighting)
        self.lighting = Lighting(
            self.rig.lamps,
            self.conditions.lamp_e,
            self.rig.beam_sigma_deg,
            self.conditions.ambient_e,
        )
        self.optics = {
            cam.name: CameraOptics(cam, self.conditions.wavelength_nm) for cam in self.rig.cameras
        }
        self.prnu = {cam.name: prnu_map(cam) for cam in self.rig.cameras}
        sky_rng = np.random.default_rng([settings.seed, 0x5C7])
        self.sky = Sky.random(self.conditions.sky_e, self.conditions.cloud_amplitude, sky_rng)
        self.sun_angle_rad = {
            cam.name: math.radians(cam.tilt_deg + math.copysign(12.0, cam.tilt_deg or 1.0))
            for cam in self.rig.cameras
        }
        self.scans = self.motion.scans
        self.chunk_scans = settings.chunk_scans
        self.wire_names = [w.name for w in self.scene.wires]
        self.sign = self.motion.direction_sign

    # -- the run ---------------------------------------------------------------------------

    @property
    def chunk_count(self) -> int:
        return -(-self.scans // self.chunk_scans)

    def header(self) -> RunHeader:
        """The run's header (FORMATS.md root attributes and shape)."""
        return RunHeader(
            line=self.settings.line,
            track=self.settings.track,
            vehicle=self.rig.name,
            direction=self.settings.direction,
            start_chainage_m=self.motion.header_start_chainage_m,
            started_at=self.started_at,
            scan_rate_hz=self.settings.scan_rate_hz,
            scans=self.scans,
            camera_pixels={c.name: c.pixels for c in self.rig.cameras},
            camera_bit_depth={c.name: c.bit_depth for c in self.rig.cameras},
        )

    @property
    def started_at(self) -> str:
        if self.settings.started_at:
            return self.settings.started_at
        return (
            "2024-06-12T11:00:00.000Z" if self.conditions.daylight else "2024-06-12T23:30:00.000Z"
        )

    def chunks(self, start: int = 0) -> Iterator[Chunk]:
        """Every chunk from ``start``, rendered one at a time."""
        for index in range(start, self.chunk_count):
            yield self.chunk(index)

    def sensor_range(self, index: int) -> tuple[int, int]:
        """Sensor sample indices ``[first, stop)`` chunk ``index`` contributes to a recording."""

        def boundary(chunk: int) -> int:
            if chunk <= 0:
                return self.motion.sensor_index_before(0.0) - 1
            if chunk >= self.chunk_count:
                last_t = float(self.motion.scan_times(self.scans - 1, 1)[0])
                return self.motion.sensor_index_before(last_t) + 3
            t = float(self.motion.scan_times(chunk * self.chunk_scans, 1)[0])
            return self.motion.sensor_index_before(t) + 1

        return boundary(index), boundary(index + 1)

    # -- one chunk -------------------------------------------------------------------------

    def chunk(self, index: int) -> Chunk:
        """Render chunk ``index`` (scans ``index * chunk_scans`` onward)."""
        first = index * self.chunk_scans
        n = min(self.chunk_scans, self.scans - first)
        if n <= 0:
            raise IndexError(f"chunk {index} is past the run's {self.scans} scans")
        motion = self.motion
        t = motion.scan_times(first, n)
        distance = motion.distance_m(t)
        chainage = motion.chainage_m(t)
        position = motion.encoder_m(t)
        pose = motion.pose(t)
        left, right, lateral = pose.sensors(self.geometry.sensor_baseline_mm)
        roll = pose.roll_rad

        wires = self.scene.sample(chainage)
        x_track = self.sign * wires.stagger_mm
        slope = wires.slope_mm_per_m / 1000.0
        theta = np.arctan(np.abs(slope))
        cos_theta = np.cos(theta)
        w0 = np.where(wires.present, wires.wear_width_mm, np.nan)
        x_roof, z_roof = track_to_roof(
            x_track, wires.height_mm, left[:, None], right[:, None], lateral[:, None], self.geometry
        )
        present = wires.present
        x_roof = np.where(present, x_roof, np.nan)
        z_roof = np.where(present, z_roof, np.nan)

        up_x = -np.sin(roll)[:, None]
        up_z = np.cos(roll)[:, None]
        layers: list[Layer] = []
        wire_layer: dict[int, int] = {}
        for m, wire in enumerate(self.scene.wires):
            rows = np.flatnonzero(present[:, m])
            if rows.shape[0] == 0:
                continue
            radius = wire.radius_mm
            if wire.contact:
                half = 0.5 * wires.wear_width_mm[rows, m]
                above = np.sqrt(np.maximum(radius * radius - half * half, 0.0))
            else:
                above = np.full(rows.shape[0], radius)
            shape = WireSection(
                centre_x_mm=x_roof[rows, m] + above * up_x[rows, 0],
                centre_z_mm=z_roof[rows, m] + above * up_z[rows, 0],
                angle_rad=roll[rows],
                semi_x_mm=radius / cos_theta[rows, m],
                semi_z_mm=np.full(rows.shape[0], radius),
                face_z_mm=-above,
            )
            if wire.contact:
                layer = Layer(
                    wire.name, rows, shape, MATERIALS["wire_side"], MATERIALS["worn_face"]
                )
            else:
                layer = Layer(wire.name, rows, shape, MATERIALS["messenger"])
            wire_layer[m] = len(layers)
            layers.append(layer)
        layers += self._fitting_layers(chainage, left, right, lateral, roll)

        glare = self._glare(distance)
        lines: dict[str, UInt8Array | UInt16Array] = {}
        cameras: dict[str, CameraTruth] = {}
        nan = np.full(present.shape, np.nan)
        for number, cam in enumerate(self.rig.cameras):
            optics = self.optics[cam.name]
            prints = [footprint(optics, layer.shape) for layer in layers]
            background = sky_e(optics, self.sky, distance)
            electrons = render_electrons(
                optics,
                layers,
                background,
                self.lighting,
                subsamples=self.settings.subsamples,
                blur=self.settings.blur,
                footprints=prints,
            )
            if cam.name == self.settings.sun_blind and np.any(glare > 0):
                electrons += sun_glare_e(
                    optics.pixel_angle, self.sun_angle_rad[cam.name], glare, cam.full_well_e
                ).astype(np.float32)
            rng = (
                np.random.default_rng([self.settings.seed, 0x1A6E, index, number])
                if self.settings.noise
                else None
            )
            lines[cam.name] = expose(
                electrons, cam, rng, prnu=self.prnu[cam.name], shot_noise=self.settings.shot_noise
            )
            camera_truth = CameraTruth(
                optics.model.project(x_roof, z_roof), nan.copy(), nan.copy(), nan.copy(), nan.copy()
            )
            for m, i in wire_layer.items():
                rows = layers[i].rows
                fp = prints[i]
                camera_truth.left_px[rows, m] = fp.left
                camera_truth.right_px[rows, m] = fp.right
                if self.scene.wires[m].contact:
                    camera_truth.face_left_px[rows, m] = fp.face_left
                    camera_truth.face_right_px[rows, m] = fp.face_right
            cameras[cam.name] = camera_truth

        contact = np.array([w.contact for w in self.scene.wires])[None, :]
        dims = self.scene.wire_type
        radius = dims.radius_mm
        residual = np.where(
            contact,
            (dims.height_mm - radius) + np.sqrt(np.maximum(radius**2 - (w0 / 2.0) ** 2, 0.0)),
            np.nan,
        )
        truth = ChunkTruth(
            distance_m=distance,
            chainage_m=chainage,
            speed_m_s=motion.speed_m_s(t),
            roll_deg=np.degrees(roll),
            lateral_mm=pose.lateral_mm,
            bounce_mm=pose.bounce_mm,
            left_mm=left,
            right_mm=right,
            sun_glare=glare,
            present=present,
            running=present & contact & (wires.lift_mm < RUNNING_LIFT_MM),
            x_roof_mm=x_roof,
            z_roof_mm=z_roof,
            stagger_mm=np.where(present, x_track, np.nan),
            height_mm=np.where(present, wires.height_mm, np.nan),
            wear_width_mm=np.where(contact, w0, np.nan),
            wear_width_inplane_mm=np.where(contact, w0 / cos_theta, np.nan),
            residual_thickness_mm=residual,
            stagger_angle_deg=np.where(present, np.degrees(theta), np.nan),
            lift_mm=np.where(present & contact, wires.lift_mm, np.nan),
            cameras=cameras,
        )
        sensor_first, sensor_stop = self.sensor_range(index)
        sensors = motion.sensor_samples(sensor_first, sensor_stop)
        return Chunk(
            index=index,
            first_scan=first,
            time_s=t,
            position_m=position,
            lines=lines,
            sensors=sensors,
            vehicle=self.vehicle_at(t),
            truth=truth,
        )

    def vehicle_at(self, t: FloatArray) -> VehicleSamples:
        """The noisy displacement sensors linearly interpolated to scan times ``t``."""
        motion = self.motion
        first = motion.sensor_index_before(float(t[0]))
        stop = motion.sensor_index_before(float(t[-1])) + 2
        samples = motion.sensor_samples(first, stop)
        return VehicleSamples(
            time_s=t.copy(),
            left_mm=np.interp(t, samples.time_s, samples.left_mm),
            right_mm=np.interp(t, samples.time_s, samples.right_mm),
            lateral_mm=np.interp(t, samples.time_s, samples.lateral_mm),
            fault=np.zeros(t.shape, dtype=bool),
        )

    def processed_vehicle_at(
        self, t: FloatArray, cutoff_hz: float = DEFAULT_FILTER_HZ
    ) -> VehicleSamples:
        """The displacement sensors at scan times ``t`` as ``catenary process`` gives them from
        the recording: its samples smoothed below ``cutoff_hz`` without phase lag and
        interpolated (:mod:`catenary.measurement.sensors`). Only the samples within the
        filter's reach of ``t`` are drawn, so a section costs what it covers."""
        motion = self.motion
        interval_s = 1.0 / self.settings.sensor_rate_hz
        smoother = SensorSmoother(cutoff_hz, interval_s)
        reach = smoother.margin + 2
        recorded_first = self.sensor_range(0)[0]
        recorded_stop = self.sensor_range(self.chunk_count - 1)[1]
        first = max(recorded_first, motion.sensor_index_before(float(t[0])) - reach)
        stop = min(recorded_stop, motion.sensor_index_before(float(t[-1])) + 2 + reach)
        samples = motion.sensor_samples(first, stop)
        values = np.stack((samples.left_mm, samples.right_mm, samples.lateral_mm))
        stream = SensorStream(
            lambda a, b: (samples.time_s[a:b], values[:, a:b]),
            stop - first,
            DEFAULT_MAX_GAP_FACTOR * interval_s,
            stop - first,
            smoother,
        )
        return stream.at(t)

    def _glare(self, distance_m: FloatArray) -> FloatArray:
        """Sun glare strength per scan: ``sun_blind_strength`` over ``sun_blind_span``, ramped
        in and out over 3 m."""
        if self.settings.sun_blind is None:
            return np.zeros_like(distance_m)
        low, high = self.settings.sun_blind_span
        start = low * self.settings.length_m
        stop = high * self.settings.length_m
        ramp_in = np.clip((distance_m - start) / 3.0, 0.0, 1.0)
        ramp_out = np.clip((stop - distance_m) / 3.0, 0.0, 1.0)
        strength = self.settings.sun_blind_strength * np.minimum(ramp_in, ramp_out)
        return np.asarray(strength, dtype=np.float64)

    def _fitting_layers(
        self,
        chainage: FloatArray,
        left: FloatArray,
        right: FloatArray,
        lateral: FloatArray,
        roll: FloatArray,
    ) -> list[Layer]:
        """One layer per fitting the scanning plane cuts in these scans."""
        fittings = self.scene.fittings
        layers: list[Layer] = []
        for f in fittings.near(float(chainage.min()), float(chainage.max())):
            offset = np.abs(chainage - fittings.chainage_m[f]) * 1000.0
            reach = fittings.reach_mm[f]
            rows = np.flatnonzero(offset < reach)
            if rows.shape[0] == 0:
                continue
            along = offset[rows]
            curved = int(fittings.curved[f])
            shrink = np.sqrt(np.maximum(1.0 - (along / reach) ** 2, 1e-6))
            ones = np.ones(rows.shape[0])
            half_w = np.full(rows.shape[0], fittings.half_width_mm[f])
            half_h = np.full(rows.shape[0], fittings.half_height_mm[f])
            scale_x = ones
            scale_z = ones
            if curved == 1:
                half_w = half_w * shrink
                scale_x = shrink
            elif curved == 2:
                half_h = half_h * shrink
                scale_z = shrink
            x_track = np.full(rows.shape[0], self.sign * fittings.y_mm[f])
            h_track = np.full(rows.shape[0], fittings.h_mm[f])
            cx, cz = track_to_roof(
                x_track, h_track, left[rows], right[rows], lateral[rows], self.geometry
            )
            shape = Bar(
                centre_x_mm=cx,
                centre_z_mm=cz,
                angle_rad=roll[rows] + self.sign * fittings.angle_rad[f],
                half_width_mm=half_w,
                half_height_mm=half_h,
                normal_scale_x=scale_x,
                normal_scale_z=scale_z,
            )
            kind = str(fittings.kind[f])
            layers.append(Layer(kind, rows, shape, MATERIALS[_FITTING_MATERIAL[kind]]))
        return layers
