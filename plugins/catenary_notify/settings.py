"""Reading a notifier's settings: known keys only, typed values, secrets from the environment.

A notifier's ``check`` reads what the config file holds (the core calls it when it reads the
configuration); its ``send`` reads the same and then the environment variables they name.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any


class SettingsError(ValueError):
    """A channel's settings are wrong for its notifier (one line naming the key)."""


def check_keys(notifier: str, settings: Mapping[str, Any], known: set[str]) -> None:
    unknown = sorted(set(settings) - known)
    if unknown:
        raise SettingsError(
            f"{notifier} settings: unknown key {unknown[0]!r} (known: {', '.join(sorted(known))})"
        )


def text(notifier: str, settings: Mapping[str, Any], key: str, default: str | None = None) -> str:
    """A required (or defaulted) non-empty string."""
    value = settings.get(key, default)
    if not isinstance(value, str) or not value:
        raise SettingsError(f"{notifier} settings: {key} must be a non-empty string, not {value!r}")
    return value


def seconds(notifier: str, settings: Mapping[str, Any], key: str, default: float) -> float:
    value = settings.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float) or value <= 0:
        raise SettingsError(f"{notifier} settings: {key} must be a positive number, not {value!r}")
    return float(value)


def variable_name(notifier: str, key: str, variable: Any) -> str:
    """The name of an environment variable that setting ``key`` gives (not its value)."""
    if not isinstance(variable, str) or not variable:
        raise SettingsError(
            f"{notifier} settings: {key} must name an environment variable, not {variable!r}"
        )
    return variable


def from_environment(notifier: str, key: str, variable: Any) -> str:
    """The value of the environment variable named by setting ``key``."""
    variable = variable_name(notifier, key, variable)
    value = os.environ.get(variable)
    if value is None:
        raise SettingsError(
            f"{notifier} settings: environment variable {variable} ({key}) is not set"
        )
    return value


def refuse_secret(notifier: str, settings: Mapping[str, Any], key: str) -> None:
    """A secret written into the config file is refused: it belongs in ``{key}_env``."""
    if key in settings:
        raise SettingsError(
            f"{notifier} settings: {key} may not be written in the config file; name the "
            f"environment variable that holds it in {key}_env"
        )
