"""``mercury-dem adjust-bal FILE``: run the bundle adjustment on a BAL problem."""

from __future__ import annotations

import argparse
import json
import time

from mercury_dem.config import Config

NAME = "adjust-bal"
HELP = "bundle-adjust a 'Bundle Adjustment in the Large' text file and print the costs"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="BAL problem file (e.g. problem-49-7776-pre.txt)")
    p.add_argument("--json", action="store_true", help="print a JSON record instead of text")
    p.add_argument("--max-iterations", type=int, default=None, help="iteration limit (default: adjust.max_iterations)")
    p.add_argument("--solver", choices=("auto", "direct", "pcg"), default=None, help="reduced system solver (default: adjust.solver)")
    p.add_argument("--loss", choices=("none", "huber", "cauchy"), default="none", help="robust loss (default none, as the BAL papers)")


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.adjust.bal import adjust_bal  # numba kernels: imported when the command runs
    from mercury_dem.adjust.solver import SolverOptions
    from mercury_dem.exceptions import AdjustmentError
    from mercury_dem.io.bal import read_bal

    t0 = time.perf_counter()
    problem = read_bal(args.file)
    read_s = time.perf_counter() - t0
    cfg = config.adjust
    opt = SolverOptions(
        max_iterations=args.max_iterations or cfg.max_iterations,
        function_tolerance=2.0 * cfg.sigma0_tolerance,
        step_tolerance=cfg.step_tolerance,
        loss=args.loss,
        loss_scale=cfg.robust_scale,
        solver=args.solver or cfg.solver,
        direct_max_unknowns=cfg.direct_max_unknowns,
        pcg_tolerance=cfg.pcg_tolerance,
        pcg_max_iterations=cfg.pcg_max_iterations,
    )
    try:
        _, res = adjust_bal(problem, opt)
    except AdjustmentError as exc:  # name the file (the library's message names the problem only)
        raise AdjustmentError(f"{args.file}: {exc}") from None
    record = {
        "file": str(args.file),
        "cameras": problem.n_cameras,
        "points": problem.n_points,
        "observations": problem.n_observations,
        "initial_cost": res.initial_cost,
        "final_cost": res.final_cost,
        "iterations": res.iterations,
        "converged": res.converged,
        "reason": res.reason,
        "linear_solver": res.linear_method,
        "read_seconds": read_s,
        "solver_seconds": res.seconds,
        "cost_per_iteration": [e["cost"] for e in res.log],
        "seconds_per_iteration": [e["elapsed"] for e in res.log],
    }
    if args.json:
        print(json.dumps(record, indent=2))
    else:
        print(f"{args.file}: {problem.n_cameras} cameras, {problem.n_points} points, {problem.n_observations} observations")
        print(f"initial cost  {res.initial_cost:.10e}")
        print(f"final cost    {res.final_cost:.10e}")
        print(f"iterations    {res.iterations} ({res.reason})")
        print(f"seconds       {res.seconds:.3f} solve ({res.linear_method}), {read_s:.3f} read")
    return 0
