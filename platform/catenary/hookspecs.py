"""Deprecated: the plugin contract is ``catenary.plugins.hookspecs``."""

from catenary.deprecated import moved
from catenary.plugins.hookspecs import *  # noqa: F403
from catenary.plugins.hookspecs import PROJECT, hookimpl, hookspec

__all__ = ["PROJECT", "hookimpl", "hookspec"]

moved("catenary.hookspecs", "catenary.plugins.hookspecs")
