"""Bundle adjustment: a sparse Schur-complement Levenberg-Marquardt engine.

Public API::

    bundle_adjust(problem, config) -> AdjustmentResult       # planetary framing cameras
    AdjustmentProblem(...)                                    # the arrays it works on
    problem_from_network(network, cameras, positions, rotations, config)  (mercury_dem.adjust.network)
    diagnose(problem) -> Diagnosis                            # islands, under-determined unknowns
    text_report / images_table / points_table / residuals_table / write_adjustment_report
    read_bal, BalModel, adjust_bal                            # Bundle Adjustment in the Large
    levenberg_marquardt(model, state, SolverOptions)          # the generic core
"""

from mercury_dem.adjust.bal import BalModel, BalProblem, adjust_bal, bal_cost, read_bal
from mercury_dem.adjust.bundle import bundle_adjust
from mercury_dem.adjust.diagnose import Diagnosis, diagnose
from mercury_dem.adjust.problem import AdjustmentProblem
from mercury_dem.adjust.report import images_table, points_table, residuals_table, text_report, write_adjustment_report
from mercury_dem.adjust.result import AdjustmentResult
from mercury_dem.adjust.solver import SolverOptions, SolverResult, levenberg_marquardt

__all__ = [
    "AdjustmentProblem", "AdjustmentResult", "BalModel", "BalProblem", "Diagnosis", "SolverOptions", "SolverResult",
    "adjust_bal", "bal_cost", "bundle_adjust", "diagnose", "images_table", "levenberg_marquardt", "points_table",
    "read_bal", "residuals_table", "text_report", "write_adjustment_report",
]
