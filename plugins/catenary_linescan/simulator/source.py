"""The simulator as an acquisition source: ``open_simulation(settings)`` streams a run.

The stream has the run's ``header`` (:class:`catenary.domain.RunHeader`) and yields
:class:`catenary.domain.ScanBlock` s of any size from ``blocks(block_scans)``: the simulation
renders fixed chunks (so the scans do not depend on the block size) and the stream cuts them
into blocks, holding at most one chunk and one block. Each block's ``vehicle`` holds the noisy
displacement sensors interpolated to the scan times. ``chunks()`` gives the rendered chunks
with their ground truth (:class:`.simulation.Chunk`). Settings: :mod:`.settings`.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

from catenary.domain import CameraLines, RunHeader, ScanBlock, VehicleSamples

from .settings import SimulationSettings, parse_settings
from .simulation import Chunk, Simulation

__all__ = ["SimulationStream", "open_simulation"]


class SimulationStream:
    """An open simulated acquisition (the ``ScanStream`` protocol)."""

    def __init__(self, simulation: Simulation) -> None:
        self.simulation = simulation
        self.header: RunHeader = simulation.header()
        self._closed = False

    def chunks(self) -> Iterator[Chunk]:
        """The rendered chunks with their ground truth."""
        return self.simulation.chunks()

    def blocks(self, block_scans: int = 1024) -> Iterator[ScanBlock]:
        """Stream the run in blocks of ``block_scans`` scans (the last may be shorter)."""
        if isinstance(block_scans, bool) or not isinstance(block_scans, int) or block_scans < 1:
            raise ValueError(f"block_scans must be a positive integer, got {block_scans!r}")
        if self._closed:
            raise ValueError("simulation stream is closed")
        return self._blocks(block_scans)

    def _blocks(self, block_scans: int) -> Iterator[ScanBlock]:
        bit_depth = self.header.camera_bit_depth
        pending: list[Chunk] = []
        held = 0
        first_scan = 0
        offset = 0  # scans of pending[0] already given out

        def take(count: int) -> ScanBlock:
            nonlocal held, offset
            parts: list[tuple[Chunk, int, int]] = []
            need = count
            while need:
                chunk = pending[0]
                stop = min(chunk.scans, offset + need)
                parts.append((chunk, offset, stop))
                need -= stop - offset
                if stop == chunk.scans:
                    pending.pop(0)
                    offset = 0
                else:
                    offset = stop
            held -= count

            def cat(get: Any) -> np.ndarray[Any, Any]:
                return np.concatenate([get(c)[a:b] for c, a, b in parts])

            vehicle = VehicleSamples(
                time_s=cat(lambda c: c.vehicle.time_s),
                left_mm=cat(lambda c: c.vehicle.left_mm),
                right_mm=cat(lambda c: c.vehicle.right_mm),
                lateral_mm=cat(lambda c: c.vehicle.lateral_mm),
                fault=cat(lambda c: c.vehicle.fault),
            )
            cameras = {
                name: CameraLines(cat(lambda c, n=name: c.lines[n]), bit_depth[name])
                for name in bit_depth
            }
            return ScanBlock(
                first_scan=first_scan,
                position_m=cat(lambda c: c.position_m),
                time_s=cat(lambda c: c.time_s),
                cameras=cameras,
                vehicle=vehicle,
            )

        for chunk in self.simulation.chunks():
            pending.append(chunk)
            held += chunk.scans
            while held >= block_scans:
                block = take(block_scans)
                first_scan += block.scans
                yield block
        if held:
            yield take(held)

    def close(self) -> None:
        self._closed = True


def open_simulation(settings: Mapping[str, Any] | SimulationSettings) -> SimulationStream:
    """Start a simulated acquisition from simulation settings (:mod:`.settings`).

    Raises :class:`catenary.errors.UserError` for bad settings or an unreadable rig file.
    """
    parsed = settings if isinstance(settings, SimulationSettings) else parse_settings(settings)
    return SimulationStream(Simulation(parsed))
