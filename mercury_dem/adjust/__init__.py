"""Bundle adjustment: a sparse Schur-complement Levenberg-Marquardt engine.

Public API::

    bundle_adjust(problem, config) -> AdjustmentResult       # planetary framing cameras
    AdjustmentProblem(...)                                    # the arrays it works on
    problem_from_network(network, cameras, positions, rotations, config)  (mercury_dem.adjust.network)
    diagnose(problem) -> Diagnosis                            # islands, under-determined unknowns
    text_report / images_table / points_table / residuals_table  (files: mercury_dem.io.adjustment_report)
    parse_bal, BalModel, adjust_bal                           # Bundle Adjustment in the Large (files: io.bal)
    levenberg_marquardt(model, state, SolverOptions)          # the generic core
"""

from mercury_dem.adjust.bal import BalModel, BalProblem, adjust_bal, bal_cost, parse_bal
from mercury_dem.adjust.bundle import bundle_adjust
from mercury_dem.adjust.diagnose import Diagnosis, diagnose
from mercury_dem.adjust.problem import AdjustmentProblem
from mercury_dem.adjust.report import images_table, points_table, residuals_table, text_report
from mercury_dem.adjust.result import AdjustmentResult
from mercury_dem.adjust.solver import SolverOptions, SolverResult, levenberg_marquardt

__all__ = [
    "AdjustmentProblem", "AdjustmentResult", "BalModel", "BalProblem", "Diagnosis", "SolverOptions", "SolverResult",
    "adjust_bal", "bal_cost", "bundle_adjust", "diagnose", "images_table", "levenberg_marquardt", "parse_bal",
    "points_table", "residuals_table", "text_report",
]
