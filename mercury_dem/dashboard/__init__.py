"""The live run dashboard (Bokeh server app): ``mercury-dem dashboard RUN``."""

from mercury_dem.dashboard.app import dashboard_app, free_port, serve
from mercury_dem.dashboard.data import dashboard_data

__all__ = ["dashboard_app", "dashboard_data", "free_port", "serve"]
