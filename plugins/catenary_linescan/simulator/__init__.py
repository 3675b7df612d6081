"""Line-scan camera simulator: renders what each camera sees for a rig and a catenary scene.

The test bed of the project: physical rendering of contact wires (with their worn flat face),
messengers, droppers and steady arms under the paper's lighting, with the vehicle's motion and
displacement sensors, written as FORMATS.md runs and calibration captures with ground truth
beside them. See ``README.md`` in this directory.

Public API
----------
open_simulation(settings) -> SimulationStream   an acquisition source (ScanStream protocol)
simulate_run(out, ...)                          what ``catenary simulate`` does
record_run(path, settings)                      write run + truth + mast register
write_captures(path, rig)                       write calibration captures + truth
load_rig(path) -> SimRig                        read a simulated rig TOML
"""

from __future__ import annotations

from .captures import render_captures, write_captures
from .command import simulate_run
from .rig import SimRig, load_rig
from .run import record_run
from .settings import DEMO_RIG_PATH, parse_settings
from .simulation import Simulation
from .source import SimulationStream, open_simulation

__all__ = [
    "DEMO_RIG_PATH",
    "SimRig",
    "Simulation",
    "SimulationStream",
    "load_rig",
    "open_simulation",
    "parse_settings",
    "record_run",
    "render_captures",
    "simulate_run",
    "write_captures",
]
