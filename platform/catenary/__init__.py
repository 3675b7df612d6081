"""catenary: contact wire wear platform.

The packages by concern: ``plugins`` (the plugin API), ``measurement`` (run file to per-span
wear), ``maintenance`` (alerts, forecasts, notifications, reports, scheduler), ``storage``
(database and runs) and ``cli`` (the commands); ``domain``, ``arrays``, ``wiretype``,
``limits``, ``config`` and ``errors`` are shared by all of them.
"""

from typing import Any


def __getattr__(name: str) -> Any:
    """``catenary.hookimpl``, the 0.1 path of ``catenary.plugins.hookimpl``: deprecated."""
    if name == "hookimpl":
        from catenary.deprecated import moved
        from catenary.plugins import hookimpl

        moved("catenary.hookimpl", "catenary.plugins.hookimpl")
        return hookimpl
    raise AttributeError(f"module 'catenary' has no attribute {name!r}")
