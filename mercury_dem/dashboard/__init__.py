"""The live run dashboard (Bokeh server app): ``mercury-dem dashboard RUN``."""

from mercury_dem.dashboard.app import dashboard_app, free_port, serve
from mercury_dem.dashboard.data import dashboard_data
from mercury_dem.dashboard.embed import EmbeddedDashboard, embed

__all__ = ["EmbeddedDashboard", "dashboard_app", "dashboard_data", "embed", "free_port", "serve"]
