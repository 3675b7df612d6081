"""The plugin's commands: ``calibrate``, ``simulate`` and ``demo``.

Only their options live here, so that ``catenary --help`` lists them without importing the
numerical modules: each command imports its implementation when it runs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from catenary.plugins import CommandContext, database_option, pass_command_context

__all__ = ["calibrate", "demo", "simulate"]


@click.command("calibrate")
@click.argument("captures", type=click.Path(path_type=Path, dir_okay=False, exists=True))
@click.option(
    "--vehicle",
    "vehicle_path",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False, exists=True),
    help="Vehicle geometry TOML (FORMATS.md).",
)
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="Rig calibration TOML to write.",
)
@click.option(
    "--distortion",
    type=click.Choice(["auto", "on", "off"]),
    default="auto",
    show_default=True,
    help="Estimate the radial lens term when the data support it, always, or never.",
)
@click.option(
    "--approximate",
    "approximate_path",
    type=click.Path(path_type=Path, dir_okay=False, exists=True),
    help="An earlier rig calibration, to assign targets a camera does not all see.",
)
@click.option("--pixels", type=click.IntRange(min=2), help="Line width (CSV point lists only).")
def calibrate(**options: Any) -> None:
    """Calibrate a rig from CAPTURES (.h5 calibration captures or a .csv point list)."""
    from catenary_linescan.calibrate import calibrate_rig

    calibrate_rig(**options)


@click.command("simulate")
@click.argument("out", type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--rig",
    "rig_path",
    type=click.Path(path_type=Path, dir_okay=False),
    show_default="the demo rig, calibration/demo-rig.sim.toml",
    help="Simulated rig (TOML: vehicle, cameras, lamps).",
)
@click.option("--length-m", type=float, default=300.0, show_default=True, help="Run length.")
@click.option(
    "--seed",
    type=int,
    default=0,
    show_default=True,
    help="Motion, encoder errors and noise; the scene too, without --scene-seed.",
)
@click.option(
    "--scene-seed",
    type=int,
    default=None,
    help="Scene alone (masts, wires, wear); default: --seed. One scene seed with different "
    "seeds: the same line under different runs.",
)
@click.option(
    "--lighting",
    type=click.Choice(["night", "day-filter", "day-white"]),
    default="night",
    show_default=True,
    help="Night (rig lamps), day with blue strobe + band-pass filter, or day with white lamps.",
)
@click.option("--overlap/--no-overlap", default=True, show_default=True, help="An overlap mid-run.")
@click.option("--sun-blind", metavar="CAMERA", help="Blind CAMERA by the sun for a stretch.")
@click.option(
    "--captures",
    "captures_path",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Also write calibration captures of the rig (and their truth) here.",
)
@click.option("--speed-kmh", type=float, default=60.0, show_default=True)
@click.option("--scan-rate-hz", type=float, default=1000.0, show_default=True)
@click.option(
    "--direction",
    type=click.Choice(["increasing", "decreasing"]),
    default="increasing",
    show_default=True,
)
@click.option("--wire-type", default="CTA120", show_default=True)
@click.option(
    "--curve-radius-m",
    type=float,
    default=None,
    help="0: straight; > 0: a curve over the second half; default: the seed decides.",
)
@click.option(
    "--turnout-angle-deg",
    type=float,
    default=None,
    help="A turnout mid-run: its diverging contact wire crosses the main one at this angle "
    "in plan (2-10; needs --no-overlap).",
)
@click.option(
    "--roi",
    metavar="CAMERA=OFFSET:WIDTH",
    multiple=True,
    help="Record CAMERA's sensor pixels OFFSET to OFFSET+WIDTH-1 only, with attribute "
    "offset_px (a region of interest; repeatable).",
)
@click.option("--overwrite", is_flag=True, help="Replace existing output files.")
def simulate(**options: Any) -> None:
    """Simulate a recorded run OUT.h5 of the rig over a generated section of line.

    Writes OUT.h5 (FORMATS.md run), OUT.truth.h5 (ground truth) and OUT.masts.csv (mast
    register) side by side.
    """
    from catenary_linescan.simulator.command import simulate_run

    simulate_run(**options)


@click.command("demo")
@click.option(
    "--out",
    type=click.Path(path_type=Path, file_okay=False),
    default=Path("catenary-demo"),
    show_default=True,
    help="Folder for the demo's files (created; files in it are replaced).",
)
@click.option("--length-m", type=float, default=300.0, show_default=True, help="Run length.")
@click.option("--seed", type=int, default=7, show_default=True, help="Scene, motion and noise.")
@database_option
@pass_command_context
def demo(context: CommandContext, /, **options: Any) -> None:
    """Simulate a run on the demo rig, calibrate the rig, process the run, write its reports."""
    from catenary_linescan.demo import run_demo

    run_demo(context, **options)
