"""Line-scan stereovision (the paper's method): camera model, calibration, simulator, processor.

Registers the ``calibrate``, ``demo`` and ``simulate`` commands, the ``simulator``
acquisition source and the ``linescan-stereo`` processor. Modules are imported inside the
hooks so that the registry reports a failure here by name.
"""

from __future__ import annotations

from catenary.plugins import hookimpl
from catenary.plugins.types import Command, Processor, Source


@hookimpl
def catenary_commands() -> list[Command]:
    from catenary_linescan.commands import calibrate, demo, simulate

    return [Command("calibrate", calibrate), Command("demo", demo), Command("simulate", simulate)]


@hookimpl
def catenary_sources() -> list[Source]:
    from catenary_linescan.simulator.source import open_simulation

    return [
        Source(
            "simulator",
            "Physical line-scan simulator: a generated section of line, rendered per camera",
            open_simulation,
        )
    ]


@hookimpl
def catenary_processors() -> list[Processor]:
    from catenary_linescan.processor.stereo import create

    return [
        Processor(
            "linescan-stereo",
            "Line-scan stereovision (the paper): profile features, N-camera matching, wire "
            "tracking, wear width from the worn face's edges",
            create,
        )
    ]
