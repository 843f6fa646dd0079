"""``mercury-dem dashboard RUN``: a live web page of a run (tile states, progress, σ0, timings)."""

from __future__ import annotations

import argparse
import sys

from mercury_dem.config import Config

NAME = "dashboard"
HELP = "serve a live dashboard of a run (tile map by state, progress, convergence) on 127.0.0.1"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", metavar="RUN", help="run directory (running, finished, or not started yet)")
    p.add_argument("--port", type=int, default=5006, help="port (default 5006; 0 picks a free one)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to bind (default 127.0.0.1: this machine only; use an SSH tunnel to look remotely)")
    p.add_argument("--interval", type=float, default=1.0, help="seconds between polls of the run store (default 1)")
    p.add_argument("--dask-dashboard", metavar="URL", help="link to the Dask dashboard when the run does not record one")


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.dashboard.app import serve

    server = serve(args.run_dir, port=args.port, host=args.host, interval_ms=int(args.interval * 1000),
                   dask_link=args.dask_dashboard)
    print(f"mercury-dem dashboard of {args.run_dir}: http://{args.host}:{server.port}/ (Ctrl-C to stop)",
          file=sys.stdout, flush=True)
    try:
        server.io_loop.start()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
    return 0
