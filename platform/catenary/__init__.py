"""catenary: contact wire wear platform."""

from catenary.hookspecs import hookimpl

__all__ = ["hookimpl"]
