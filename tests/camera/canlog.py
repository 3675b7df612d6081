"""A CAN log of the vehicle sensors for recording live cameras with ``--vehicle-source can``."""

from __future__ import annotations

from pathlib import Path

import can

from catenary_can.decode import DEFAULT_METRES_PER_PULSE
from catenary_can.reader import load_database

PERIOD_S = 0.005


def can_log(path: Path, start_unix_s: float, seconds: float, speed_mps: float) -> Path:
    """A BLF log of the CAN sensors from ``start_unix_s``: the encoder at ``speed_mps`` and
    steady displacement sensors, every 5 ms (UNIX timestamps, as a live bus gives)."""
    database = load_database()
    encoder = database.get_message_by_name("WheelEncoder")
    sensors = database.get_message_by_name("DisplacementSensors")
    steady = {"left_mm": 2.0, "right_mm": -1.0, "lateral_mm": 3.0, "status": 0}
    with can.Logger(path) as logger:
        for i in range(round(seconds / PERIOD_S)):
            t = start_unix_s + i * PERIOD_S
            pulses = round(speed_mps * i * PERIOD_S / DEFAULT_METRES_PER_PULSE)
            for message, signals in (
                (encoder, {"pulse_count": pulses, "status": 0, "counter": i % 16}),
                (sensors, {**steady, "counter": i % 16}),
            ):
                logger.on_message_received(
                    can.Message(
                        timestamp=t,
                        arbitration_id=message.frame_id,
                        is_extended_id=False,
                        data=message.encode(signals),
                    )
                )
    return path
