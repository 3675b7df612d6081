"""The train's motion: speed, encoder, car body pose and the displacement sensors.

Everything is a deterministic function of time (or of the sample index for sensor noise), so
any block of scans can be computed on its own and memory never grows with the run:

- **Speed** ``v(t) = v0 (1 + Σ a_k sin(ω_k t + φ_k))``: a few percent of slow variation
  (periods 20-120 s); the true distance ``s(t)`` is its exact integral.
- **Scans** are triggered at the constant ``scan_rate_hz``: scan ``i`` at ``t = i / rate``.
- **Encoder**: ``position_m = pulse · floor(s (1 + ε) / pulse)`` with a scale error ``ε`` (a few
  tenths of a percent: wheel wear, slip) and a pulse of ``encoder_pulse_mm``.
- **Chainage**: ``c(t) = c0 + d · s(t)`` (``d = ±1`` by direction); the run's header gets
  ``c0`` plus a start error (the position known at the start is only as good as the marker).
- **Body pose** relative to the track: roll ``φ`` (positive = left side up), lateral
  displacement and bounce, each a smooth random process (a sum of sinusoids of random
  frequency and phase in the body modes' band, scaled to the given standard deviation; peaks
  reach about three times that) plus, in curves, a quasi-static part: the body rolls outward
  by ``curve_roll_deg`` and shifts outward by ``curve_shift_mm`` (unbalanced lateral
  acceleration), and its centre lies inward of the track centre line by the versine of the
  bogie pitch ``a² / (8 R)`` (the car body is a chord of the curve). These ramp in and out
  over 20 m at the curve's ends, the roll and shift saturating smoothly (full at R <= 1500 m).
- **Displacement sensors** (FORMATS.md vehicle compensation model, exactly): from the pose,
  ``left = bounce + (b/2) tan φ``, ``right = bounce - (b/2) tan φ``, ``lateral = lateral``,
  sampled on their own clock (``sensor_rate_hz``, a random phase against the scans) with
  Gaussian noise ``sensor_noise_mm``. Noise is drawn per page of 1024 samples from the seed,
  so a sample's value does not depend on how the run is cut into blocks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from catenary.arrays import FloatArray, IntArray
from catenary.domain import VehicleGeometry
from catenary.errors import UserError

__all__ = ["Motion", "MotionParams", "Pose", "SensorSamples"]

_PAGE = 1024
_CURVE_RAMP_M = 20.0


@dataclass(frozen=True)
class MotionParams:
    """How the train runs (module docstring); None draws a value from the seed."""

    speed_kmh: float = 60.0
    speed_variation: float = 0.04
    scan_rate_hz: float = 1000.0
    direction: str = "increasing"
    encoder_scale_error: float | None = None  # random: N(0, 0.003), within ±0.006
    encoder_pulse_mm: float = 1.25
    start_chainage_error_m: float | None = None  # random: U(-3, 3)
    roll_std_deg: float = 0.25
    lateral_std_mm: float = 8.0
    bounce_std_mm: float = 5.0
    curve_roll_deg: float = 0.6
    curve_shift_mm: float = 10.0
    bogie_pitch_m: float = 17.5
    sensor_rate_hz: float = 200.0
    sensor_noise_mm: float = 0.3

    def check(self) -> None:
        """``UserError`` for values outside what the model means."""
        if not 1.0 <= self.speed_kmh <= 400.0:
            raise UserError(f"speed must be 1-400 km/h, got {self.speed_kmh}")
        if not 10.0 <= self.scan_rate_hz <= 100000.0:
            raise UserError(f"scan rate must be 10-100000 Hz, got {self.scan_rate_hz}")
        if self.direction not in ("increasing", "decreasing"):
            raise UserError(f"direction must be increasing or decreasing, got {self.direction!r}")
        if not 1.0 <= self.sensor_rate_hz <= 100000.0:
            raise UserError(f"sensor rate must be 1-100000 Hz, got {self.sensor_rate_hz}")
        if self.encoder_pulse_mm <= 0:
            raise UserError(f"encoder pulse must be positive, got {self.encoder_pulse_mm} mm")
        if not 0.0 <= self.speed_variation < 0.5:
            raise UserError(f"speed variation must be 0-0.5, got {self.speed_variation}")


@dataclass(frozen=True)
class Pose:
    """The car body relative to the track at ``n`` times, each ``[n]``."""

    roll_rad: FloatArray
    lateral_mm: FloatArray
    bounce_mm: FloatArray

    def sensors(self, baseline_mm: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Exact ``(left_mm, right_mm, lateral_mm)`` of the FORMATS.md model for this pose."""
        half = 0.5 * baseline_mm * np.tan(self.roll_rad)
        return self.bounce_mm + half, self.bounce_mm - half, self.lateral_mm.copy()


@dataclass(frozen=True)
class SensorSamples:
    """Displacement sensor samples ``[k]`` on the scan clock (noise included)."""

    index: IntArray
    time_s: FloatArray
    left_mm: FloatArray
    right_mm: FloatArray
    lateral_mm: FloatArray


class _Process:
    """A smooth zero-mean random process: a sum of sinusoids with a given standard deviation."""

    def __init__(self, rng: np.random.Generator, std: float, band_hz: tuple[float, float]):
        count = 12
        self.omega = 2.0 * math.pi * rng.uniform(*band_hz, count)
        self.phase = rng.uniform(0.0, 2.0 * math.pi, count)
        weight = rng.rayleigh(1.0, count)
        self.amp = std * weight / math.sqrt(0.5 * float(np.sum(weight**2)))

    def __call__(self, t: FloatArray) -> FloatArray:
        t = np.asarray(t, dtype=np.float64)
        return np.asarray(
            np.sin(t[..., None] * self.omega + self.phase) @ self.amp, dtype=np.float64
        )


class Motion:
    """The train's motion for one run (module docstring).

    Parameters
    ----------
    params : MotionParams
    seed : int
    length_m : float
        True distance the run covers; the run has ``scans`` scans.
    start_chainage_m : float
        True chainage of the first scan.
    geometry : VehicleGeometry
        For the sensor baseline.
    curve : (start_m, end_m, curvature_per_m)
        The line's curve in chainage (line frame, +: bending right), for the quasi-static pose.
    """

    def __init__(
        self,
        params: MotionParams,
        seed: int,
        length_m: float,
        start_chainage_m: float,
        geometry: VehicleGeometry,
        curve: tuple[float, float, float] = (math.inf, math.inf, 0.0),
    ) -> None:
        params.check()
        self.params = params
        self.geometry = geometry
        self.seed = int(seed)
        rng = np.random.default_rng([self.seed, 0x40710])
        self.v0 = params.speed_kmh / 3.6
        count = 3
        self._v_omega = 2.0 * math.pi / rng.uniform(20.0, 120.0, count)
        self._v_phase = rng.uniform(0.0, 2.0 * math.pi, count)
        self._v_amp = params.speed_variation * rng.dirichlet(np.ones(count))
        error = params.encoder_scale_error
        self.encoder_scale_error = (
            float(np.clip(rng.normal(0.0, 0.003), -0.006, 0.006)) if error is None else error
        )
        start_error = params.start_chainage_error_m
        self.start_chainage_error_m = (
            float(rng.uniform(-3.0, 3.0)) if start_error is None else start_error
        )
        self.direction_sign = 1.0 if params.direction == "increasing" else -1.0
        self.start_chainage_m = float(start_chainage_m)
        self.length_m = float(length_m)
        self._roll = _Process(rng, math.radians(params.roll_std_deg), (0.2, 1.0))
        self._lateral = _Process(rng, params.lateral_std_mm, (0.1, 0.8))
        self._bounce = _Process(rng, params.bounce_std_mm, (0.8, 2.0))
        self.sensor_phase_s = float(rng.uniform(-1.0, 0.0) / params.sensor_rate_hz)
        self._curve = curve
        self.duration_s = self._time_at(self.length_m)
        self.scans = math.floor(self.duration_s * params.scan_rate_hz) + 1

    # -- time and distance -----------------------------------------------------------------

    def distance_m(self, t: FloatArray) -> FloatArray:
        """True distance travelled since the first scan [m] at times ``t`` [s]."""
        t = np.asarray(t, dtype=np.float64)
        wave = np.cos(self._v_phase) - np.cos(t[..., None] * self._v_omega + self._v_phase)
        return np.asarray(self.v0 * (t + wave @ (self._v_amp / self._v_omega)), np.float64)

    def speed_m_s(self, t: FloatArray) -> FloatArray:
        t = np.asarray(t, dtype=np.float64)
        return np.asarray(
            self.v0 * (1.0 + np.sin(t[..., None] * self._v_omega + self._v_phase) @ self._v_amp),
            np.float64,
        )

    def _time_at(self, distance_m: float) -> float:
        low, high = 0.0, distance_m / (self.v0 * (1.0 - self.params.speed_variation)) + 1.0
        for _ in range(80):
            mid = 0.5 * (low + high)
            if float(self.distance_m(np.array(mid))) < distance_m:
                low = mid
            else:
                high = mid
        return high

    def scan_times(self, first: int, count: int) -> FloatArray:
        """Times [s] of scans ``first .. first + count - 1``."""
        return np.arange(first, first + count, dtype=np.float64) / self.params.scan_rate_hz

    def encoder_m(self, t: FloatArray) -> FloatArray:
        """The wheel encoder's distance [m]: scale error and pulse quantisation applied."""
        pulse = self.params.encoder_pulse_mm / 1000.0
        measured = self.distance_m(t) * (1.0 + self.encoder_scale_error)
        return np.asarray(np.floor(measured / pulse + 1e-9) * pulse, dtype=np.float64)

    def chainage_m(self, t: FloatArray) -> FloatArray:
        """True chainage [m] at times ``t``."""
        return self.start_chainage_m + self.direction_sign * self.distance_m(t)

    @property
    def header_start_chainage_m(self) -> float:
        """The start chainage the run's header records (true value plus the start error)."""
        return self.start_chainage_m + self.start_chainage_error_m

    # -- pose and sensors ------------------------------------------------------------------

    def run_curvature_per_m(self, chainage_m: FloatArray) -> FloatArray:
        """Track curvature in the run's frame [1/m] (+: bending right), ramped at curve ends."""
        start, end, kappa = self._curve
        c = np.asarray(chainage_m, dtype=np.float64)
        if kappa == 0.0 or not math.isfinite(start):
            return np.zeros_like(c)

        def ramp(x: FloatArray) -> FloatArray:
            x = np.clip(x, 0.0, 1.0)
            return x * x * (3.0 - 2.0 * x)

        inside = ramp((c - start) / _CURVE_RAMP_M + 0.5) * (
            1.0 - ramp((c - end) / _CURVE_RAMP_M + 0.5)
        )
        return np.asarray(self.direction_sign * kappa * inside, dtype=np.float64)

    def pose(self, t: FloatArray) -> Pose:
        """The car body's true pose at times ``t`` [s]."""
        t = np.asarray(t, dtype=np.float64)
        kappa = self.run_curvature_per_m(self.chainage_m(t))
        p = self.params
        # full at R <= 1500 m, reached with no kink: a body on its suspension turns no corner
        # in roll or shift (a clip's corner would be a step in the roll rate)
        x = np.minimum(np.abs(kappa) * 1500.0, 1.0)
        scale = x * (2.0 - x)
        outward = -np.sign(kappa) * scale
        roll = self._roll(t) + outward * math.radians(p.curve_roll_deg)
        chord = 1000.0 * kappa * p.bogie_pitch_m**2 / 8.0  # body centre inward
        lateral = self._lateral(t) + chord + outward * p.curve_shift_mm
        bounce = self._bounce(t)
        return Pose(roll, lateral, bounce)

    def sensor_time_s(self, index: IntArray) -> FloatArray:
        """Time [s] of sensor sample ``index`` (sample 0 just before or at the first scan)."""
        return (
            self.sensor_phase_s + np.asarray(index, dtype=np.float64) / self.params.sensor_rate_hz
        )

    def sensor_index_before(self, t: float) -> int:
        """Index of the last sensor sample at or before ``t`` [s]."""
        return math.floor((t - self.sensor_phase_s) * self.params.sensor_rate_hz + 1e-9)

    def sensor_samples(self, first: int, stop: int) -> SensorSamples:
        """Sensor samples ``first .. stop - 1`` with their noise (``first`` may be negative)."""
        index = np.arange(first, stop, dtype=np.int64)
        t = self.sensor_time_s(index)
        left, right, lateral = self.pose(t).sensors(self.geometry.sensor_baseline_mm)
        sigma = self.params.sensor_noise_mm
        if sigma > 0 and index.shape[0]:
            noise = np.empty((index.shape[0], 3))
            pages = np.floor_divide(index, _PAGE)
            for page in np.unique(pages):
                rng = np.random.default_rng([self.seed, 0x5E45, int(page) + (1 << 20)])
                values = rng.standard_normal((_PAGE, 3))
                mask = pages == page
                noise[mask] = values[index[mask] - page * _PAGE]
            left = left + sigma * noise[:, 0]
            right = right + sigma * noise[:, 1]
            lateral = lateral + sigma * noise[:, 2]
        return SensorSamples(index, t, left, right, lateral)
