"""A failed unit carries a kind (UnitFailure) beside its text, set from the exception where it is caught; the
report counts failed units by kind; summaries of older runs without one still read (``unrecorded``)."""

from __future__ import annotations

import io

import pytest

from mercury_dem.exceptions import (
    AdjustmentError,
    CorruptUnitError,
    GeometryError,
    MercuryDemError,
    NetworkError,
    ReferenceDataError,
    StoreError,
)
from mercury_dem.pipeline.report import failure_counts, print_report
from mercury_dem.pipeline.results import (
    FailureSummary,
    TileSummary,
    UnitFailure,
    UnitSummary,
    failure_of,
    summary_from_json,
)


@pytest.mark.parametrize(("exc", "kind"), [
    (CorruptUnitError("tile 3: network.zarr fails its checksum"), UnitFailure.CORRUPT_INPUT),
    (StoreError("mission gone"), UnitFailure.CORRUPT_INPUT),
    (AdjustmentError("under-determined"), UnitFailure.ADJUSTMENT_FAILED),
    (GeometryError("no pose"), UnitFailure.BAD_INPUT),
    (NetworkError("dangling ids"), UnitFailure.BAD_INPUT),
    (ReferenceDataError("shots.csv: no lat"), UnitFailure.BAD_INPUT),
    (MercuryDemError("something else"), UnitFailure.OTHER),
])
def test_kind_from_the_exception_type_not_its_text(exc: BaseException, kind: UnitFailure) -> None:
    assert failure_of(exc) is kind


def test_an_exception_may_carry_its_kind() -> None:
    class NoInput(MercuryDemError):
        failure = UnitFailure.NO_INPUT

    assert failure_of(NoInput("adjustment failed, corrupt, whatever the text says")) is UnitFailure.NO_INPUT


def test_kind_stored_beside_the_text_and_old_summaries_read() -> None:
    t = TileSummary(id=4, error="tile 4: 3 pairs gave no control point", failure=UnitFailure.NO_MATCH)
    d = t.to_json()
    assert d["failure"] == "no_match" and summary_from_json(d) == t
    u = UnitSummary("region", 2, error="region 2: x", failure=UnitFailure.ADJUSTMENT_FAILED)
    assert summary_from_json(u.to_json()).failure is UnitFailure.ADJUSTMENT_FAILED
    assert "failure" not in UnitSummary("region", 1, ok=True, children=[0]).to_json()  # only failed units have one
    old = {"level": "region", "id": 2, "name": UnitSummary("region", 2).name, "ok": False, "error": "region 2: x"}
    assert summary_from_json(old).failure is None and summary_from_json(old).to_json() == old
    assert summary_from_json({**old, "failure": "from_a_newer_version"}).failure is None


def test_report_counts_failures_by_kind() -> None:
    try:
        raise RuntimeError("boom")
    except RuntimeError as exc:
        crashed = FailureSummary.of("region", 5, exc)
    summaries = {
        "tile": [TileSummary(id=1, ok=True), TileSummary(id=2, error="a", failure=UnitFailure.NO_PAIRS),
                 TileSummary(id=3, error="b", failure=UnitFailure.NO_MATCH),
                 TileSummary(id=4, error="c", failure=UnitFailure.NO_MATCH), TileSummary(id=6, error="old run")],
        "region": [crashed, UnitSummary("region", 7, error="d", failure=UnitFailure.NO_INPUT)],
        "global": [UnitSummary("global", 0, ok=True, children=[1])],
    }
    counts = failure_counts(summaries)
    assert counts == {"tile": {"no_match": 2, "no_pairs": 1, "unrecorded": 1},
                      "region": {"no_input": 1, "unexpected": 1}}
    out = io.StringIO()
    report = {"run": "r", "mission": "m", "tiles": {"non_empty": 5, "total": 5, "succeeded": 1, "failed": []},
              "images": {"input": 0, "controlled": 0, "uncontrolled": []},
              "levels": {"region": [], "hemisphere": [], "global": None}, "failures": counts}
    print_report(report, out)
    assert "failed tile units by kind: no_match 2, no_pairs 1, unrecorded 1" in out.getvalue()
