"""Pair failure kinds (:class:`mercury_dem.match.result.PairFailure`): set where found, counted without the text."""

from __future__ import annotations

from mercury_dem.match.result import PairFailure, PairReport, failed_result, failure_counts


def test_a_failed_result_carries_its_kind_and_the_kinds_status() -> None:
    """A failed result has its kind and the kind's status (skipped or failed)."""
    r = failed_result(PairReport("a", "b"), PairFailure.TOO_FEW_MATCHES, "too few matches: 3 < min_matches 20")
    assert (r.report.status, r.report.failure) == ("failed", "too_few_matches")
    assert r.points_ref.shape == (0, 2) and r.report.as_row()["failure"] == "too_few_matches"
    for kind in (PairFailure.INCIDENCE, PairFailure.SUN_AZIMUTH, PairFailure.CONVERGENCE, PairFailure.REDUNDANT):
        assert failed_result(PairReport(), kind, "x").report.status == "skipped"
    for kind in (PairFailure.IMAGE_MISSING, PairFailure.IMAGE_UNUSABLE, PairFailure.NO_PRETRANSFORM):
        assert failed_result(PairReport(), kind, "x").report.status == "failed"
    assert PairReport().failure == ""  # a matched pair has none


def test_failures_are_counted_by_kind_whatever_their_text() -> None:
    """Counts by kind, whatever the numbers in the text; redundant pairs apart."""
    reports = [PairReport(status="matched", n_matches=50)]
    for kind, text in ((PairFailure.TOO_FEW_MATCHES, "too few matches: 3 < min_matches 20 (chain 9->5)"),
                       (PairFailure.TOO_FEW_MATCHES, "too few matches: 12 < min_matches 20 (chain 40->12)"),
                       (PairFailure.IMAGE_UNUSABLE, "reference image X: blank (all pixels 0 DN)"),
                       (PairFailure.REDUNDANT, "redundant: views converge by 40 deg ..."),
                       (PairFailure.REDUNDANT, "redundant: views converge by 35 deg ...")):
        failed_result(rep := PairReport(), kind, text)
        reports.append(rep)
    failures, redundant = failure_counts(reports)
    assert failures == {"too_few_matches": 2, "image_unusable": 1}
    assert redundant == 2
    assert failure_counts([]) == ({}, 0)
