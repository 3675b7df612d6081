"""Regenerate the shipped demo captures: ``python -m catenary_linescan.simulator.demo_captures``.

Renders the calibration tool (:mod:`.captures`, default tool: targets every 100 mm over
±600 mm, heights 1300-2500 mm every 100 mm) for ``calibration/demo-rig.sim.toml`` with seed 1
and writes ``calibration/demo-captures.h5`` and ``calibration/demo-captures.truth.h5``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from .captures import write_captures
from .rig import load_rig
from .settings import DEMO_RIG_PATH

SEED = 1


def main(argv: list[str] | None = None) -> int:
    """Write the demo captures (or to the path given as the only argument)."""
    args = sys.argv[1:] if argv is None else argv
    out = Path(args[0]) if args else DEMO_RIG_PATH.with_name("demo-captures.h5")
    capture, truth = write_captures(out, load_rig(DEMO_RIG_PATH), seed=SEED)
    for path in (capture, truth):
        os.chmod(path, 0o644)
    print(f"wrote {capture} and {truth}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
