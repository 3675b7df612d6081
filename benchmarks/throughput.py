"""Benchmark: scans per second of the line-scan processor on one CPU core.

Renders a simulated section with the demo rig (four 4096-pixel cameras, 8 bits) through the
overlap, where four wires and their fittings are in view, calibrates the rig from simulated
captures, and then times only ``LineScanProcessor.process`` over the pre-rendered blocks
(features, matching, face widths, tracking) and its ``finish``. BLAS and OpenMP are held to
one thread before NumPy is imported. A second pass under ``tracemalloc`` gives the peak of
Python-visible memory the processor allocates (NumPy's buffers included); the process's peak
RSS (rendering included) is printed too.

The target is 20x the paper's 1000 scans/s: 20,000 scans/s.

    .venv/bin/python benchmarks/throughput.py                    # 8 blocks of 1024 scans
    .venv/bin/python benchmarks/throughput.py --blocks 16 --block-scans 2048
    .venv/bin/python benchmarks/throughput.py --lighting day-white --profile
"""

from __future__ import annotations

import os

for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_variable] = "1"

import argparse  # noqa: E402
import cProfile  # noqa: E402
import pstats  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

from accuracy import add_outlines_option, calibrated_rig, processor_config  # noqa: E402

from catenary.domain import CameraLines, ScanBlock  # noqa: E402
from catenary_linescan.processor.stereo import LineScanProcessor, ProcessorConfig  # noqa: E402
from catenary_linescan.simulator import Simulation, parse_settings  # noqa: E402

PAPER_SCANS_PER_S = 1000.0
TARGET_SCANS_PER_S = 20_000.0


def render_blocks(lighting: str, blocks: int, block_scans: int) -> list[ScanBlock]:
    """Consecutive blocks of a simulated run, starting a little before the overlap."""
    scans = blocks * block_scans
    sim = Simulation(
        parse_settings(
            {
                "seed": 5,
                "lighting": lighting,
                "overlap": True,
                "length_m": 300.0,
                "chunk_scans": 256,
            }
        )
    )
    first_chunk = max(0, (sim.scans // 2 - scans // 2) // sim.chunk_scans)
    bit_depth = {c.name: c.bit_depth for c in sim.rig.cameras}
    chunks = []
    for index in range(first_chunk, sim.chunk_count):
        chunks.append(sim.chunk(index))
        if sum(c.scans for c in chunks) >= scans:
            break
    lines = {n: np.concatenate([c.lines[n] for c in chunks])[:scans] for n in bit_depth}
    position = np.concatenate([c.position_m for c in chunks])[:scans]
    time_s = np.concatenate([c.time_s for c in chunks])[:scans]
    vehicle = [c.vehicle for c in chunks]
    left = np.concatenate([v.left_mm for v in vehicle])[:scans]
    right = np.concatenate([v.right_mm for v in vehicle])[:scans]
    lateral = np.concatenate([v.lateral_mm for v in vehicle])[:scans]
    first_scan = chunks[0].first_scan
    out = []
    for b in range(0, min(scans, position.shape[0]), block_scans):
        part = slice(b, b + block_scans)
        out.append(
            ScanBlock(
                first_scan=first_scan + b,
                position_m=position[part],
                time_s=time_s[part],
                cameras={n: CameraLines(lines[n][part], bit_depth[n]) for n in lines},
                vehicle=type(vehicle[0])(
                    time_s=time_s[part],
                    left_mm=left[part],
                    right_mm=right[part],
                    lateral_mm=lateral[part],
                ),
            )
        )
    return out


def stage_times(
    rig, blocks: list[ScanBlock], config: ProcessorConfig | None = None
) -> dict[str, float]:
    """CPU seconds per stage of one pass (processor settings ``config``, None: the
    defaults): features, matching (with face widths), tracking."""
    import catenary_linescan.processor.stereo as stereo
    from catenary_linescan.processor.tracking import WireTracker

    spent = {"features": 0.0, "matching": 0.0, "tracking": 0.0}
    originals = {}

    def timed(name: str, stage: str, owner: object) -> None:
        function = getattr(owner, name)
        originals[(owner, name)] = function

        def wrapper(*args, **kwargs):
            started = time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                spent[stage] += time.process_time() - started

        setattr(owner, name, wrapper)

    timed("extract_features", "features", stereo)
    for name in ("pad_candidates", "match", "face_widths_mm"):
        timed(name, "matching", stereo)
    for name in ("push", "finish"):
        timed(name, "tracking", WireTracker)
    try:
        run(LineScanProcessor(rig, config), blocks)
    finally:
        for (owner, name), function in originals.items():
            setattr(owner, name, function)
    return spent


def run(processor: LineScanProcessor, blocks: list[ScanBlock]) -> int:
    rows = 0
    for block in blocks:
        rows += processor.process(block).rows
    return rows + processor.finish().rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blocks", type=int, default=8)
    parser.add_argument("--block-scans", type=int, default=1024)
    parser.add_argument("--lighting", default="night", choices=["night", "day-filter", "day-white"])
    parser.add_argument("--repeat", type=int, default=3, help="timed passes (best is kept)")
    parser.add_argument("--profile", action="store_true", help="print the hottest functions")
    add_outlines_option(parser)
    args = parser.parse_args(argv)
    config = processor_config(args)

    with tempfile.TemporaryDirectory() as tmp:
        rig = calibrated_rig(Path(tmp))
    blocks = render_blocks(args.lighting, args.blocks, args.block_scans)
    scans = sum(b.scans for b in blocks)
    pixels = {n: c.lines.shape[1] for n, c in blocks[0].cameras.items()}
    print(
        f"{scans} scans of {len(pixels)} cameras x {max(pixels.values())} px "
        f"({args.lighting}, through an overlap), blocks of {args.block_scans}"
    )

    run(LineScanProcessor(rig, config), blocks[:1])  # warm up (imports, caches)
    best = float("inf")
    best_cpu = float("inf")
    rows = 0
    for _ in range(args.repeat):
        processor = LineScanProcessor(rig, config)
        started = time.perf_counter()
        started_cpu = time.process_time()
        rows = run(processor, blocks)
        best = min(best, time.perf_counter() - started)
        best_cpu = min(best_cpu, time.process_time() - started_cpu)
    rate = scans / best
    print(
        f"processor: {best:.3f} s for {scans} scans -> {rate:,.0f} scans/s, "
        f"{rate / PAPER_SCANS_PER_S:.1f}x the paper's 1000 scans/s "
        f"(target {TARGET_SCANS_PER_S:,.0f}: {'met' if rate >= TARGET_SCANS_PER_S else 'MISSED'})"
    )
    print(
        f"  {1e6 * best / scans:.1f} µs per scan wall, {1e6 * best_cpu / scans:.1f} µs CPU "
        f"({scans / best_cpu:,.0f} scans/s of CPU); {rows} wire observations"
    )
    stages = stage_times(rig, blocks, config)
    print(
        "  per stage (CPU µs per scan): "
        + ", ".join(f"{k} {1e6 * v / scans:.1f}" for k, v in stages.items())
    )

    tracemalloc.start()
    run(LineScanProcessor(rig, config), blocks)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    block_bytes = sum(c.lines.nbytes for c in blocks[0].cameras.values())
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(
        f"peak memory allocated by the processor: {peak / 2**20:.1f} MiB "
        f"(one block's lines: {block_bytes / 2**20:.1f} MiB); process peak RSS {rss:.0f} MiB "
        "(pre-rendered blocks and the simulator included)"
    )

    if args.profile:
        profiler = cProfile.Profile()
        profiler.enable()
        run(LineScanProcessor(rig, config), blocks)
        profiler.disable()
        pstats.Stats(profiler).sort_stats("tottime").print_stats(20)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
