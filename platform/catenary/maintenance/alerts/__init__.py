from catenary.maintenance.alerts.evaluation import *  # noqa: F403
