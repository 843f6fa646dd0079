"""The tiles' fit (RegisterOptions) and the mean level's min_shots/clip_nmad are the ``registration`` section's
keys: defaults equal to the values the code had before, a configuration without them (an older run's) loads
with those defaults, a set key reaches the fit, and a bad value is a ConfigError naming the key."""

from __future__ import annotations

import dataclasses
import inspect

import pytest

from mercury_dem.altimetry.merge import mean_level, mean_level_offsets
from mercury_dem.altimetry.register import MODELS, RegisterOptions
from mercury_dem.config import ConfigError, load_config
from mercury_dem.config.registration import RegistrationConfig

# the values hard-coded before they were configuration (issue 32)
BEFORE = {"models": ("affine", "similarity", "translation", "vertical"), "max_param_sigma_m": 10.0, "huber_k": 2.0,
          "reject_k": 5.0, "max_iterations": 20, "tolerance_m": 0.05, "min_shots": 50, "min_profile_shots": 10,
          "profile_sigma_horizontal_m": 2000.0, "profile_sigma_vertical_m": 500.0, "max_abs_height_m": 50_000.0,
          "profile_nuisance": True, "nuisance_sigma_horizontal_m": 100.0, "nuisance_sigma_vertical_m": 10.0,
          "nuisance_min_within_share": 0.05}


def test_defaults_are_the_values_before() -> None:
    assert {f.name: getattr(RegisterOptions(), f.name) for f in dataclasses.fields(RegisterOptions)} == BEFORE
    assert RegisterOptions.from_config(RegistrationConfig()) == RegisterOptions()
    assert MODELS == {"affine": 12, "similarity": 7, "translation": 3, "vertical": 1}
    for fn in (mean_level, mean_level_offsets):
        p = inspect.signature(fn).parameters
        assert (p["min_shots"].default, p["clip_nmad"].default) == (500, 10.0)
    cfg = RegistrationConfig()
    assert (cfg.level_min_shots, cfg.level_clip_nmad) == (500, 10.0)


def test_an_old_configuration_loads_and_a_set_key_reaches_the_fit() -> None:
    old = load_config(overrides={"registration": {"gap_px": 3.0}})  # written before these keys existed
    assert RegisterOptions.from_config(old.registration) == RegisterOptions()
    cfg = load_config(overrides={"registration": {"huber_k": 3.5, "models": ["translation", "vertical"],
                                                  "profile_nuisance": False, "level_min_shots": 200}})
    opt = RegisterOptions.from_config(cfg.registration)
    assert (opt.huber_k, opt.models, opt.profile_nuisance) == (3.5, ("translation", "vertical"), False)
    assert cfg.registration.level_min_shots == 200


@pytest.mark.parametrize(("key", "value"), [("models", ["shear"]), ("models", []), ("min_profile_shots", 2),
                                            ("huber_k", 0.0), ("nuisance_min_within_share", 1.5)])
def test_bad_values_name_the_key(key: str, value: object) -> None:
    with pytest.raises(ConfigError, match=f"config key .registration.{key}. "):
        load_config(overrides={"registration": {key: value}})
