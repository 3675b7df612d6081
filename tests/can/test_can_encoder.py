"""The ``can`` stream's encoder readings beside its vehicle samples, and its clock aligned to
a live scan source's."""

from __future__ import annotations

from pathlib import Path

import can
import numpy as np
import pytest

from catenary_can.decode import DEFAULT_METRES_PER_PULSE
from catenary_can.reader import load_database, open_log

DB = load_database()
DISP = DB.get_message_by_name("DisplacementSensors")
ENC = DB.get_message_by_name("WheelEncoder")
PERIOD_S = 0.005
T0 = 1_700_000_000.0


def write_log(path: Path, frames: int, *, start_s: float = 0.0, bad: int = -1) -> Path:
    """Encoder and displacement frames every 5 ms from ``T0 + start_s`` at 10 m/s; the
    encoder frame ``bad`` has its fault bit set."""
    rng = np.random.default_rng(5)
    with can.Logger(path) as logger:
        for i in range(frames):
            t = T0 + start_s + i * PERIOD_S
            pulses = round(10.0 * i * PERIOD_S / DEFAULT_METRES_PER_PULSE)
            status = 1 if i == bad else 0
            enc = ENC.encode({"pulse_count": pulses, "status": status, "counter": i % 16})
            logger.on_message_received(
                can.Message(timestamp=t, arbitration_id=0x100, is_extended_id=False, data=enc)
            )
            signals = {
                "left_mm": round(5.0 + rng.normal(0.0, 0.3), 2),
                "right_mm": round(-4.0 + rng.normal(0.0, 0.3), 2),
                "lateral_mm": round(rng.normal(0.0, 2.0), 2),
                "status": 0,
                "counter": i % 16,
            }
            logger.on_message_received(
                can.Message(
                    timestamp=t + 0.0005,
                    arbitration_id=0x110,
                    is_extended_id=False,
                    data=DISP.encode(signals),
                )
            )
    return path


def test_readings_and_samples_asked_in_turn_lose_nothing(tmp_path: Path) -> None:
    log = write_log(tmp_path / "run.blf", 400, bad=123)
    with open_log(log, chunk_frames=50) as whole:
        blocks = list(whole.read())
    want_t = np.concatenate([b.vehicle.time_s for b in blocks])
    good = np.concatenate([~b.encoder.fault for b in blocks])
    enc_t = np.concatenate([b.encoder.time_s for b in blocks])[good]
    enc_p = np.concatenate([b.encoder.position_m for b in blocks])[good]
    assert enc_t.shape == (399,)  # the faulty reading left out

    with open_log(log, chunk_frames=50) as stream:
        samples, readings = [], []
        for k, until in enumerate(np.arange(0.1, 2.2, 0.13)):
            # in either order, and the second over the same times
            first, second = (
                (stream.encoder_readings, stream.vehicle_samples)
                if k % 2
                else (stream.vehicle_samples, stream.encoder_readings)
            )
            for method in (first, second):
                parts = list(method(float(until), final=until > 2.0))
                (readings if method == stream.encoder_readings else samples).extend(parts)
    np.testing.assert_array_equal(np.concatenate([s.time_s for s in samples]), want_t)
    np.testing.assert_array_equal(np.concatenate([r.time_s for r in readings]), enc_t)
    np.testing.assert_array_equal(np.concatenate([r.position_m for r in readings]), enc_p)


def test_align_clock_sets_time_zero_unless_configured(tmp_path: Path) -> None:
    log = write_log(tmp_path / "run.blf", 40, start_s=0.5)
    with open_log(log) as stream:
        stream.align_clock(T0)
        (readings, *_) = stream.encoder_readings(np.inf, final=True)
    assert readings.time_s[0] == pytest.approx(0.5, abs=1e-6)  # on the scan source's clock
    with open_log(log, time_zero_s=T0 + 0.25) as stream:
        stream.align_clock(T0)  # configured: kept
        (readings, *_) = stream.encoder_readings(np.inf, final=True)
    assert readings.time_s[0] == pytest.approx(0.25, abs=1e-6)
    with open_log(log) as stream:
        list(stream.vehicle_samples(0.1))
        with pytest.raises(ValueError, match=r"clock aligned after frames were read"):
            stream.align_clock(T0)
