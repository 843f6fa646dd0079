"""Fuzzing the BAL reader: a damaged BAL text file gives a BalProblem or AdjustmentError naming it.

Seed: a small generated problem (3 cameras, 10 points) written as text; mutations
truncate it, delete/duplicate lines, replace tokens by huge/NaN/negative/garbage
values or change the header counts. ``MERCURY_DEM_FUZZ_EXAMPLES`` raises the number
of inputs (default 150, ~2 s).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from mercury_dem.adjust.bal import BalProblem, bal_cost
from mercury_dem.exceptions import AdjustmentError
from mercury_dem.io.bal import read_bal
from tests.fuzzing import mutate_lines


def _seed_text() -> str:
    rng = np.random.default_rng(0)
    n_cam, n_pt = 3, 10
    lines = [f"{n_cam} {n_pt} {n_cam * n_pt}"]
    for c in range(n_cam):
        for p in range(n_pt):
            lines.append(f"{c} {p} {rng.normal(0, 50):.6e} {rng.normal(0, 50):.6e}")
    for c in range(n_cam):
        cam = [*rng.normal(0, 0.1, 3), *rng.normal(0, 0.5, 2), -10.0, 500.0, 1e-2, -1e-3]
        lines.extend(f"{v:.16e}" for v in cam)
    for _ in range(n_pt):
        lines.extend(f"{v:.16e}" for v in rng.normal(0, 1, 3))
    return "\n".join(lines) + "\n"


SEED = _seed_text()
TOKENS = ("nan", "-nan", "inf", "-inf", "1e308", "1e400", "-1", "-7", "0", "2", "99999999999999999999999",
          "1.5", "-0", "0x10", "1_000", "abc", "", "\x00", "٣", "4.", "+3", "1e18", "9223372036854775808")


def _edit_bal(draw: st.DrawFn, how: str, lines: list[str], i: int) -> list[str]:
    if how == "token":
        toks = lines[i].split() or [""]
        toks[draw(st.integers(0, len(toks) - 1))] = draw(st.sampled_from(TOKENS) | st.text(max_size=6))
        lines[i] = " ".join(toks)
    elif how == "header":
        toks = lines[0].split() + ["0", "0", "0"]
        toks[draw(st.integers(0, 2))] = draw(st.sampled_from(TOKENS) | st.integers(-5, 40).map(str))
        lines[0] = " ".join(toks[:3])
    else:
        lines[i] = draw(st.text(max_size=20))
    return lines


@st.composite
def mutated_bal(draw: st.DrawFn) -> str:
    return mutate_lines(draw, SEED, ("token", "header", "bytes"), _edit_bal)


@pytest.fixture(scope="module")
def fuzz_path() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="bal_fuzz_") as d:
        yield Path(d) / "fuzzed-problem.txt"


def test_seed_reads(fuzz_path: Path) -> None:
    fuzz_path.write_text(SEED)
    prob = read_bal(fuzz_path)
    assert (prob.n_cameras, prob.n_points, prob.n_observations) == (3, 10, 30)
    assert np.isfinite(bal_cost(prob))


@settings(max_examples=int(os.environ.get("MERCURY_DEM_FUZZ_EXAMPLES", "150")), deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(text=mutated_bal())
@example(text=SEED)
@example(text=SEED.replace("\n0 0 ", "\nnan 0 ", 1))  # was: RuntimeWarning casting NaN to an index
@example(text=SEED.replace("\n0 0 ", "\n1.5 0 ", 1))  # was: silently truncated to camera 1
@example(text=SEED.replace("3 10 30", "-1 10 30", 1))  # was: negative count accepted
@example(text=SEED + "1.0\n")  # was: tokens beyond the header's counts ignored
@example(text="3 10 30\n0 0 1e400 0\n")  # huge value
@example(text=SEED.replace("\n0 0 6.286511e+00", "\n0 0 1e308", 1))  # finite, accepted
@example(text="1 1 1\n0 0 1 1\n" + "0\n" * 9 + "0\n0\n0\n")  # point in the camera's plane: ZeroDivisionError
def test_damaged_bal_gives_problem_or_adjustment_error(fuzz_path: Path, text: str) -> None:
    fuzz_path.write_bytes(text.encode("utf-8", "surrogatepass"))
    try:
        prob = read_bal(fuzz_path)
    except AdjustmentError as exc:
        assert str(fuzz_path) in str(exc)
        return
    assert isinstance(prob, BalProblem)
    m = prob.n_observations
    assert prob.camera_index.shape == prob.point_index.shape == (m,) and prob.observations.shape == (m, 2)
    assert prob.cameras.shape == (prob.n_cameras, 9) and prob.points.shape == (prob.n_points, 3)
    assert np.all((prob.camera_index >= 0) & (prob.camera_index < prob.n_cameras))
    assert np.all((prob.point_index >= 0) & (prob.point_index < prob.n_points))
    assert all(np.all(np.isfinite(a)) for a in (prob.observations, prob.cameras, prob.points))
    # the cost of what was read: a float (inf only past float64's range, for values near 1e308), or
    # AdjustmentError when a projection overflows; never NaN or an overflow warning (warnings are errors)
    try:
        cost = bal_cost(prob)
    except AdjustmentError as exc:
        assert "not finite" in str(exc)
        return
    assert cost >= 0.0 and not np.isnan(cost)


def test_cost_near_float_max_is_inf_and_adjustment_refuses(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Values near 1e308: ``bal_cost`` is inf without an overflow warning (``np.sum(r * r)`` warned), a
    representable cost of residuals ~1e150 (whose squares alone overflow) is exact to rounding, and
    ``adjust-bal`` refuses with AdjustmentError naming the file instead of iterating on inf."""
    from mercury_dem.adjust.bal import adjust_bal, half_sum_of_squares
    from mercury_dem.cli import main

    assert np.isinf(half_sum_of_squares(np.array([3e200, -4e200, 0.0])))  # 1.25e401: past the range
    assert half_sum_of_squares(np.array([3e150, 4e150])) == pytest.approx(0.5 * 25e300, rel=1e-15)
    assert half_sum_of_squares(np.array([3.0, 4.0])) == 12.5 and half_sum_of_squares(np.zeros(0)) == 0.0
    p = tmp_path / "huge-problem.txt"
    p.write_text(SEED.replace("\n0 0 6.286511e+00", "\n0 0 1e308", 1))
    prob = read_bal(p)
    assert np.isinf(bal_cost(prob))
    with pytest.raises(AdjustmentError, match="initial cost exceeds float64's range"):
        adjust_bal(prob)
    assert main(["adjust-bal", str(p)]) == 2
    assert "huge-problem.txt: BAL problem: the initial cost exceeds" in capsys.readouterr().err
