"""Record a simulated run: the run file (through the one ``RunFileWriter``), its ground truth
and the scene's mast register, side by side.

``record_run("out/sim.h5", settings)`` writes ``sim.h5`` (FORMATS.md recorded run),
``sim.truth.h5`` (:mod:`.truth`) and ``sim.masts.csv`` (FORMATS.md mast register). If anything
fails, none of the three is left behind.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from catenary.errors import UserError
from catenary.measurement.runfile import RunFileWriter

from .settings import SimulationSettings, parse_settings
from .simulation import Simulation
from .truth import TruthWriter, masts_path_for, truth_path_for, write_mast_register

__all__ = ["RecordedRun", "record_run", "roi_windows"]


@dataclass(frozen=True)
class RecordedRun:
    """What :func:`record_run` wrote."""

    run_path: Path
    truth_path: Path
    masts_path: Path
    scans: int
    vehicle_samples: int


def record_run(
    path: str | Path,
    settings: Mapping[str, Any] | SimulationSettings,
    *,
    overwrite: bool = False,
    progress: Callable[[int], None] | None = None,
    simulation: Simulation | None = None,
    roi: Mapping[str, tuple[int, int]] | None = None,
) -> RecordedRun:
    """Simulate a run and write it with its ground truth and mast register.

    Parameters
    ----------
    path : path-like
        The run file ``NAME.h5``; ``NAME.truth.h5`` and ``NAME.masts.csv`` go beside it.
    settings : mapping or SimulationSettings
        Simulation settings (:mod:`.settings`).
    overwrite : bool
        Replace existing files (else ``UserError`` if any exists).
    progress : callable, optional
        Called with the number of scans written after every chunk.
    simulation : Simulation, optional
        An already built simulation of these settings.
    roi : mapping of camera name to ``(offset_px, width)``, optional
        Cameras that record a region of interest: the rendered lines cut to sensor pixels
        ``offset_px .. offset_px + width - 1``, written with ``offset_px`` (FORMATS.md).
    """
    run_path = Path(path)
    parsed = settings if isinstance(settings, SimulationSettings) else parse_settings(settings)
    sim = simulation if simulation is not None else Simulation(parsed)
    truth_path = truth_path_for(run_path)
    masts_path = masts_path_for(run_path)
    if not overwrite:
        for existing in (run_path, truth_path, masts_path):
            if existing.exists():
                raise UserError(f"{existing}: already exists (not overwritten)")
    if not run_path.parent.is_dir():
        raise UserError(f"{run_path.parent}: no such directory")
    header = sim.header()
    windows = roi_windows(sim, roi or {})
    created: list[Path] = []
    samples = 0
    try:
        with RunFileWriter(
            run_path,
            line=header.line,
            track=header.track,
            vehicle=header.vehicle,
            direction=header.direction,
            start_chainage_m=header.start_chainage_m,
            started_at=header.started_at,
            scan_rate_hz=header.scan_rate_hz,
            cameras={
                c.name: (windows[c.name].stop - windows[c.name].start, c.bit_depth)
                for c in sim.rig.cameras
            },
            offsets_px={name: offset for name, (offset, _) in (roi or {}).items()},
            overwrite=overwrite,
        ) as writer:
            created.append(run_path)
            with TruthWriter(truth_path, sim, run_file=run_path.name) as truth:
                created.append(truth_path)
                for chunk in sim.chunks():
                    lines = {name: line[:, windows[name]] for name, line in chunk.lines.items()}
                    writer.append(chunk.position_m, chunk.time_s, lines)
                    s = chunk.sensors
                    writer.append_vehicle(s.time_s, s.left_mm, s.right_mm, s.lateral_mm)
                    samples += s.time_s.shape[0]
                    truth.append(chunk)
                    if progress is not None:
                        progress(chunk.scans)
        write_mast_register(masts_path, sim)
        created.append(masts_path)
    except BaseException:
        for file in created:
            file.unlink(missing_ok=True)
        raise
    return RecordedRun(run_path, truth_path, masts_path, sim.scans, samples)


def roi_windows(sim: Simulation, roi: Mapping[str, tuple[int, int]]) -> dict[str, slice]:
    """Each camera's recorded pixels: its region of interest in ``roi``, else the sensor;
    ``UserError`` for a camera the rig lacks or a region outside the sensor."""
    pixels = {c.name: c.pixels for c in sim.rig.cameras}
    for name in roi:
        sim.rig.camera(name)  # UserError naming the rig's cameras
    windows = {name: slice(0, n) for name, n in pixels.items()}
    for name, (offset, width) in roi.items():
        if not (offset >= 0 and width >= 1 and offset + width <= pixels[name]):
            raise UserError(
                f"region of interest of camera {name!r}: offset_px {offset} and width {width} "
                f"do not lie within its {pixels[name]} pixels"
            )
        windows[name] = slice(offset, offset + width)
    return windows
