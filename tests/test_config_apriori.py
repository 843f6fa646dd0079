"""One a-priori pointing uncertainty (µrad): declared by the mission, overridable once (issue 20 item 5)."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mercury_dem.config import Config, config_template, load_config, to_dict
from mercury_dem.config.apriori import RETIRED_KEYS, adjust_config_with_sigma, resolve_pointing_sigma_urad
from mercury_dem.exceptions import ConfigError
from mercury_dem.pipeline.stages import adjust_config_for, match_config_for


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
    """The stage configurations equal what the three keys gave before (mission-declared sigma, bit for bit)."""
    rng = np.random.default_rng(20)
    for sigma in [450.0, 5000.0, *rng.uniform(1.0, 1e4, 20)]:
        mission = SimpleNamespace(pointing_sigma_urad=float(sigma), path="m")
        m = match_config_for(mission, load_config())  # type: ignore[arg-type]
        a = adjust_config_for(mission, load_config())  # type: ignore[arg-type]
        assert m.pointing_sigma_urad == float(sigma)
        assert a.pointing_sigma_deg == float(np.degrees(float(sigma) * 1e-6))  # the pre-session-11 conversion
        over = load_config(overrides={"apriori": {"pointing_sigma_urad": 123.0}})
        assert match_config_for(mission, over).pointing_sigma_urad == 123.0  # type: ignore[arg-type]
        assert adjust_config_for(mission, over).pointing_sigma_deg == float(np.degrees(123.0 * 1e-6))  # type: ignore[arg-type]
    assert adjust_config_with_sigma(load_config().adjust, None).pointing_sigma_deg == 0.2  # no mission, no override
    with pytest.raises(ConfigError, match="declares no"):
        match_config_for(SimpleNamespace(pointing_sigma_urad=None, path="m"), load_config())  # type: ignore[arg-type]
