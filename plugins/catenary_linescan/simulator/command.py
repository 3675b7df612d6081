"""``catenary simulate``: record a simulated run with its ground truth (and captures)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from catenary.errors import UserError

from .captures import write_captures
from .run import record_run
from .settings import DEMO_RIG_PATH, parse_settings
from .simulation import Simulation

__all__ = ["simulate"]


@click.command("simulate")
@click.argument("out", type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--rig",
    "rig_path",
    type=click.Path(path_type=Path, dir_okay=False),
    default=DEMO_RIG_PATH,
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
@click.option("--overwrite", is_flag=True, help="Replace existing output files.")
def simulate(
    out: Path,
    rig_path: Path,
    length_m: float,
    seed: int,
    scene_seed: int | None,
    lighting: str,
    overlap: bool,
    sun_blind: str | None,
    captures_path: Path | None,
    speed_kmh: float,
    scan_rate_hz: float,
    direction: str,
    wire_type: str,
    curve_radius_m: float | None,
    overwrite: bool,
) -> None:
    """Simulate a recorded run OUT.h5 of the rig over a generated section of line.

    Writes OUT.h5 (FORMATS.md run), OUT.truth.h5 (ground truth) and OUT.masts.csv (mast
    register) side by side.
    """
    settings: dict[str, Any] = {
        "rig": rig_path,
        "length_m": length_m,
        "seed": seed,
        "scene_seed": scene_seed,
        "lighting": lighting,
        "overlap": overlap,
        "sun_blind": sun_blind,
        "speed_kmh": speed_kmh,
        "scan_rate_hz": scan_rate_hz,
        "direction": direction,
        "wire_type": wire_type,
        "curve_radius_m": curve_radius_m,
    }
    try:
        parsed = parse_settings(settings)
        simulation = Simulation(parsed)
        if captures_path is not None:
            if captures_path.exists() and not overwrite:
                raise UserError(f"{captures_path}: already exists (not overwritten)")
            if not captures_path.parent.is_dir():
                raise UserError(f"{captures_path.parent}: no such directory")
        label = f"simulating {out.name}"
        with click.progressbar(length=simulation.scans, label=label, show_pos=True) as bar:
            recorded = record_run(
                out, parsed, overwrite=overwrite, progress=bar.update, simulation=simulation
            )
        click.echo(
            f"wrote {recorded.run_path} ({recorded.scans} scans), {recorded.truth_path}, "
            f"{recorded.masts_path}"
        )
        if captures_path is not None:
            capture, truth = write_captures(captures_path, parsed.rig, seed=seed)
            click.echo(f"wrote {capture} and {truth}")
    except UserError as exc:
        raise click.ClickException(str(exc)) from None
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        raise click.ClickException(f"{where}{exc.strerror or exc}") from None
