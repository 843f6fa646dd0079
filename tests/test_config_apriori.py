"""One a-priori pointing uncertainty (µrad): declared by the mission, overridable once (issue 20 item 5)."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mercury_dem.adjust.blocked_bundle import blocked_bundle_adjust
from mercury_dem.adjust.bundle import bundle_adjust
from mercury_dem.adjust.problem import pointing_sigma_radians
from mercury_dem.config import Config, config_template, load_config, to_dict
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.config.apriori import (
    MISSIONLESS_POINTING_SIGMA_URAD,
    RETIRED_KEYS,
    missionless_pointing_sigma_urad,
    resolve_pointing_sigma_urad,
)
from mercury_dem.config.match import MatchConfig
from mercury_dem.exceptions import AdjustmentError, ConfigError
from mercury_dem.pipeline.stages import pointing_sigma_urad_for
from mercury_dem.validate.synthetic_network import make_synthetic_network


@pytest.mark.parametrize("key", sorted(RETIRED_KEYS))
def test_a_retired_key_in_a_file_is_refused_naming_the_new_key(tmp_path: Path, key: str) -> None:
    section, _, name = key.partition(".")
    text = f"{section}:\n  {name}: 1\n" if name else f"{section}:\n  preset: tiny\n"
    (tmp_path / "old.yaml").write_text(text)
    with pytest.raises(ConfigError) as exc:
        load_config(tmp_path / "old.yaml")
    msg = str(exc.value)
    assert f"'{key}'" in msg and "old.yaml" in msg
    assert "apriori.pointing_sigma_urad" in msg or "mercury-dem synth" in msg


def test_a_retired_key_in_overrides_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"'adjust.pointing_sigma_deg'.*apriori.pointing_sigma_urad"):
        load_config(overrides={"adjust": {"pointing_sigma_deg": 0.2}})


def test_the_run_configuration_has_one_pointing_key_and_no_generator_section() -> None:
    tree = to_dict(Config())
    assert "synth" not in tree and tree["apriori"] == {"pointing_sigma_urad": None}
    assert "pointing_sigma_deg" not in tree["adjust"] and "pointing_sigma_urad" not in tree["match"]
    text = config_template()
    keys = re.findall(r"^\s*(\w*pointing_sigma\w*):", text, flags=re.M)
    assert keys == ["pointing_sigma_urad"] and "apriori:" in text and "synth:" not in text
    # a recorded configuration loads back as it was (the adjust command reloads run.json's)
    cfg = load_config(overrides={"apriori": {"pointing_sigma_urad": 700.0}})
    assert load_config(overrides=to_dict(cfg)) == cfg


def test_the_override_wins_then_the_mission_then_an_error_naming_the_mission() -> None:
    assert resolve_pointing_sigma_urad(300.0, 450.0, "m") == 300.0
    assert resolve_pointing_sigma_urad(None, 450.0, "m") == 450.0
    with pytest.raises(ConfigError, match=r"mission /data/moon declares no .*apriori.pointing_sigma_urad"):
        resolve_pointing_sigma_urad(None, None, "/data/moon")
    with pytest.raises(ConfigError, match="apriori.pointing_sigma_urad"):
        load_config(overrides={"apriori": {"pointing_sigma_urad": -1.0}})


def test_matching_and_adjustment_get_the_same_sigma_converted_as_before() -> None:
    """One resolved value in µrad for both stages; the adjusters' radians are the pre-session-11 conversion
    (through degrees) bit for bit; the library's match and adjust sections carry no copy of it.
    """
    rng = np.random.default_rng(20)
    for sigma in [450.0, 5000.0, *rng.uniform(1.0, 1e4, 20)]:
        mission = SimpleNamespace(pointing_sigma_urad=float(sigma), path="m")
        assert pointing_sigma_urad_for(mission, load_config()) == float(sigma)  # type: ignore[arg-type]
        assert pointing_sigma_radians(float(sigma)) == float(np.radians(math.degrees(float(sigma) * 1e-6)))
        over = load_config(overrides={"apriori": {"pointing_sigma_urad": 123.0}})
        assert pointing_sigma_urad_for(mission, over) == 123.0  # type: ignore[arg-type]
    # no mission, no override: 0.2 deg as before (to the last bit but one)
    assert missionless_pointing_sigma_urad(None) == MISSIONLESS_POINTING_SIGMA_URAD
    assert pointing_sigma_radians(MISSIONLESS_POINTING_SIGMA_URAD) == pytest.approx(float(np.radians(0.2)), rel=1e-15)
    assert missionless_pointing_sigma_urad(700.0) == 700.0
    with pytest.raises(ConfigError, match="declares no"):
        pointing_sigma_urad_for(SimpleNamespace(pointing_sigma_urad=None, path="m"), load_config())  # type: ignore[arg-type]
    assert not [f.name for c in (MatchConfig, AdjustConfig) for f in dataclasses.fields(c) if "pointing" in f.name]


def test_an_adjustment_problem_without_a_pointing_sigma_is_refused() -> None:
    """Both adjusters refuse a problem that states no a-priori pointing sigma, naming the key to set."""
    net = make_synthetic_network(600, rng=np.random.default_rng(1), min_views=3, outlier_fraction=0.0)
    bare = dataclasses.replace(net.problem, pointing_sigma_urad=None)
    for solve in (bundle_adjust, blocked_bundle_adjust):
        with pytest.raises(AdjustmentError, match="apriori.pointing_sigma_urad"):
            solve(bare)
    with pytest.raises(AdjustmentError, match="positive"):
        dataclasses.replace(net.problem, pointing_sigma_urad=0.0)
