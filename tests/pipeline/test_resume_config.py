"""Resuming a run: a changed configuration that changes results is refused naming its section; execution is not."""

from __future__ import annotations

from pathlib import Path

import pytest

from mercury_dem.config import load_config, to_dict
from mercury_dem.exceptions import StoreError
from mercury_dem.io.run_store import RunStore
from mercury_dem.pipeline.graph import changed_sections, prepare_store


def test_changed_sections_skips_execution_only() -> None:
    a = {"dem": {"pixels_per_degree": 4.0}, "execution": {"workers": 2}, "match": {"max_matches": 400}}
    b = {"dem": {"pixels_per_degree": 8.0}, "execution": {"workers": 4}, "match": {"max_matches": 400}}
    assert changed_sections(a, b) == ["dem"]
    assert changed_sections(a, {**a, "execution": {"workers": 9}}) == []
    assert changed_sections(a, {k: v for k, v in a.items() if k != "match"}) == ["match"]


def test_a_parameter_added_since_the_run_counts_as_its_default() -> None:
    """A run made before ``adjust.rms_flag_px`` existed resumes when it keeps its default; another value is a change."""
    old = {"adjust": {"reject_k_mad": 3.0}, "dem": {"pixels_per_degree": 4.0}}
    defaults = {"adjust": {"reject_k_mad": 3.0, "rms_flag_px": 2.0}, "dem": {"pixels_per_degree": 8.0}}
    new = {"adjust": {"reject_k_mad": 3.0, "rms_flag_px": 2.0}, "dem": {"pixels_per_degree": 4.0}}
    assert changed_sections(old, new, defaults) == []
    assert changed_sections(old, new) == ["adjust"]  # without the defaults: the new key is a difference
    assert changed_sections(old, {**new, "adjust": {"reject_k_mad": 3.0, "rms_flag_px": 5.0}}, defaults) == ["adjust"]
    assert changed_sections({**old, "adjust": {"reject_k_mad": 4.0}}, new, defaults) == ["adjust"]


def _started_run(mission: Path, out: Path, config_overrides: dict) -> None:
    """A run store as a started run leaves it: run.json with the mission and the configuration."""
    store = RunStore(out)
    out.mkdir(parents=True)
    store.write_run({"mission": str(mission.resolve()), "config": to_dict(load_config(overrides=config_overrides))})


def test_resume_with_other_execution_settings_is_allowed(tiny_mission_path: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    _started_run(tiny_mission_path, out, {"execution": {"workers": 2, "no_worker_timeout_s": 300}})
    store = prepare_store(tiny_mission_path, out,
                          load_config(overrides={"execution": {"workers": 4, "no_worker_timeout_s": 30}}), None)
    assert store.has_run()


def test_resume_with_another_dem_grid_is_refused_naming_the_section(tiny_mission_path: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    _started_run(tiny_mission_path, out, {"dem": {"pixels_per_degree": 4.0}})
    with pytest.raises(StoreError, match=r"different configuration \(section dem\).*--force"):
        prepare_store(tiny_mission_path, out, load_config(overrides={"dem": {"pixels_per_degree": 8.0}}), None)
