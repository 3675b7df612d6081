"""The import paths of catenary 0.1 that plugins may use, kept for one release: each warns
(``DeprecationWarning``) and names its new place, ``catenary.plugins`` for the plugin API."""

from __future__ import annotations

import warnings

__all__ = ["moved"]


def moved(old: str, new: str) -> None:
    """Warn that ``old`` is deprecated in favour of ``new`` (at the importer's line)."""
    warnings.warn(
        f"{old} is deprecated and goes in the next release: use {new}",
        DeprecationWarning,
        stacklevel=3,
    )
