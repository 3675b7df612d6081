"""A stored run's samples file: where it lies, and the run's profile for a comparison."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from catenary.compare import RunProfile
from catenary.config import Settings
from catenary.errors import UserError
from catenary.samples import read_sample_batches
from catenary.storage.models import Run

__all__ = ["run_profile", "samples_file"]


def samples_file(settings: Settings, run: Run) -> Path:
    """The run's samples Parquet file (``Run.samples_path``, relative to the data directory
    unless absolute)."""
    if not run.samples_path:
        raise UserError(f"run {run.id} has no samples file")
    path = Path(run.samples_path)
    return path if path.is_absolute() else settings.data_dir / path


def run_profile(settings: Settings, run: Run) -> RunProfile:
    """The run's samples for ``compare_profiles``: those without a vehicle sensor fault, the
    stagger in the line frame (positive to the right looking toward increasing chainage)."""
    columns = ["chainage_m", "wire", "stagger_mm", "residual_thickness_mm", "vehicle_fault"]
    parts = list(read_sample_batches(samples_file(settings, run), columns))
    values = {c: np.concatenate([p[c] for p in parts]) for c in columns} if parts else None
    if values is None:
        raise UserError(f"run {run.id} has no samples")
    good = ~values["vehicle_fault"]
    sign = 1.0 if run.direction == "increasing" else -1.0
    return RunProfile(
        chainage_m=values["chainage_m"][good],
        wire=values["wire"][good].astype(np.int64),
        stagger_mm=sign * values["stagger_mm"][good],
        residual_thickness_mm=values["residual_thickness_mm"][good],
    )
