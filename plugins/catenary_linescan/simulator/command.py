"""What ``catenary simulate`` does: record a simulated run with its ground truth (and captures)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from catenary.errors import UserError

from .captures import write_captures
from .run import record_run, roi_windows
from .settings import DEMO_RIG_PATH, parse_settings
from .simulation import Simulation

__all__ = ["simulate_run"]


def simulate_run(
    out: Path,
    rig_path: Path | None,
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
    roi: tuple[str, ...] = (),
    turnout_angle_deg: float | None = None,
) -> None:
    """Simulate a recorded run ``out`` (with its truth and mast register beside it) of the rig
    at ``rig_path`` (None: the demo rig), and its calibration captures at ``captures_path``;
    ``roi``: regions of interest, each ``CAMERA=OFFSET:WIDTH``."""
    settings: dict[str, Any] = {
        "rig": rig_path or DEMO_RIG_PATH,
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
        "turnout_angle_deg": turnout_angle_deg,
    }
    try:
        regions = _regions(roi)
        parsed = parse_settings(settings)
        simulation = Simulation(parsed)
        roi_windows(simulation, regions)  # refused before anything is written
        if captures_path is not None:
            if captures_path.exists() and not overwrite:
                raise UserError(f"{captures_path}: already exists (not overwritten)")
            if not captures_path.parent.is_dir():
                raise UserError(f"{captures_path.parent}: no such directory")
        label = f"simulating {out.name}"
        with click.progressbar(length=simulation.scans, label=label, show_pos=True) as bar:
            recorded = record_run(
                out,
                parsed,
                overwrite=overwrite,
                progress=bar.update,
                simulation=simulation,
                roi=regions,
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


def _regions(values: tuple[str, ...]) -> dict[str, tuple[int, int]]:
    """``--roi CAMERA=OFFSET:WIDTH`` values by camera; ``UserError`` naming a malformed one."""
    regions: dict[str, tuple[int, int]] = {}
    for value in values:
        name, _, window = value.partition("=")
        offset, _, width = window.partition(":")
        if not (name and offset.isdigit() and width.isdigit()) or name in regions:
            raise UserError(
                f"--roi {value!r}: expected CAMERA=OFFSET:WIDTH (whole pixels), once per camera"
            )
        regions[name] = (int(offset), int(width))
    return regions
