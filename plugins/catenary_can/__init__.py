"""CAN bus acquisition: displacement sensors and wheel encoder (python-can, cantools).

Registers the ``can`` acquisition source: the three displacement sensors of the vehicle
compensation model (FORMATS.md) and the wheel encoder, read over CAN from a live bus
(socketcan or any python-can interface, chosen in the settings) or from a log file (BLF,
ASC, CSV, python-can's formats), decoded with the DBC shipped here
(``vehicle_sensors.dbc``: frame 0x100 ``WheelEncoder``, 0x110 ``DisplacementSensors``,
both every 5 ms; layout and units in :mod:`catenary_can.decode`).

It is a *vehicle sensor source*: its stream (:class:`catenary_can.reader.CanSensorStream`)
gives no scans, only timestamped vehicle samples with dropped frames, stuck and
out-of-range sensors and status faults flagged (``VehicleSamples.fault``), plus encoder
positions. ``catenary record OUT.h5 --source simulator --vehicle-source can
--vehicle-option log=run.blf`` takes the scans from the scan source and the vehicle samples
from this one (``vehicle_samples(until_s, final=...)``), writing both through the run file
writer; the encoder's readings (``encoder_readings``) give free-running cameras' scans their
positions, or check encoder-triggered ones, and ``align_clock`` puts a live camera source's
scan time 0 on the bus's clock (:mod:`catenary.measurement.recording`). Settings:
:mod:`catenary_can.reader`. Modules are imported inside the hook so that the registry reports
a failure here by name.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from catenary.plugins import hookimpl
from catenary.plugins.types import VehicleSource, VehicleStream


def open_can_source(settings: Mapping[str, Any]) -> VehicleStream:
    """Open the ``can`` source (settings: :mod:`catenary_can.reader`)."""
    from catenary_can.reader import open_can

    return open_can(settings)


@hookimpl
def catenary_vehicle_sources() -> list[VehicleSource]:
    return [
        VehicleSource(
            "can",
            "Vehicle sensors over CAN (displacement sensors and wheel encoder; live bus or log "
            "file, DBC decoding)",
            open_can_source,
        )
    ]
