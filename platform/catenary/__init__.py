"""catenary: contact wire wear platform.

The packages by concern: ``plugins`` (the plugin API), ``measurement`` (run file to per-span
wear), ``maintenance`` (alerts, forecasts, notifications, reports, scheduler), ``storage``
(database and runs) and ``cli`` (the commands); ``domain``, ``wiretype``, ``limits``,
``config`` and ``errors`` are shared by all of them.
"""
