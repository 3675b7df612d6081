"""The benchmark scripts imported as modules (``benchmarks/`` is not a package)."""

from __future__ import annotations

import sys
from pathlib import Path
from types import ModuleType

import pytest

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.fixture(scope="module")
def sweep() -> ModuleType:
    """``benchmarks/sweep.py``."""
    sys.path.insert(0, str(BENCHMARKS))
    try:
        import sweep as module
    finally:
        sys.path.remove(str(BENCHMARKS))
    return module
