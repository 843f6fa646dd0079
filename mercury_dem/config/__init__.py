"""The typed configuration tree of mercury_dem.

One frozen dataclass per stage, each in its own module of this package, joined
by :class:`Config`. Loaded from YAML (``load_config``), validated on
construction (errors name the key and the allowed range), printed as a commented
template (``mercury-dem config --template``) and recorded in every run's report.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.config.apriori import AprioriConfig, refuse_retired_keys
from mercury_dem.config.base import ConfigSection, from_dict, section, template, to_dict
from mercury_dem.config.dem import DemConfig
from mercury_dem.config.dense import DenseConfig
from mercury_dem.config.execution import ExecutionConfig
from mercury_dem.config.match import MatchConfig
from mercury_dem.config.network import NetworkConfig
from mercury_dem.config.reference import ReferenceConfig
from mercury_dem.config.registration import RegistrationConfig
from mercury_dem.config.tiling import TilingConfig
from mercury_dem.config.yaml_loader import DuplicateKeyError, safe_load_unique
from mercury_dem.exceptions import ConfigError


@dataclass(frozen=True)
class Config(ConfigSection):
    """The run configuration: one section per stage (the generator's settings are ``synth``'s flags)."""

    tiling: TilingConfig = section(TilingConfig, "Tile grid, regions and overlap search")
    apriori: AprioriConfig = section(AprioriConfig, "A-priori uncertainty of the mission's pointing "
                                     "(null: the mission's declared value)")
    match: MatchConfig = section(MatchConfig, "Feature matching per tile")
    network: NetworkConfig = section(NetworkConfig, "Control networks: tracks and merging")
    adjust: AdjustConfig = section(AdjustConfig, "Bundle adjustment at every level")
    dem: DemConfig = section(DemConfig, "DEM gridding")
    registration: RegistrationConfig = section(RegistrationConfig, "The DEM registered to laser altimetry per tile "
                                               "and merged with it (when dem.register_to_altimetry)")
    dense: DenseConfig = section(DenseConfig, "Dense stereo: pairs, chips, matching, the dense cloud and DEM "
                                 "(issue 31)")
    execution: ExecutionConfig = section(ExecutionConfig, "Execution on Dask")
    reference: ReferenceConfig = section(ReferenceConfig, "Reference heights the DEM is compared with (real missions)")


def load_config(path: str | Path | None = None, overrides: dict[str, Any] | None = None) -> Config:
    """The default configuration, overlaid by a YAML file and then by ``overrides``.

    ``overrides`` is a nested dict (e.g. from CLI flags). Unknown keys and bad
    values raise :class:`ConfigError` naming the key.
    """
    data: dict[str, Any] = {}
    if path is not None:
        p = Path(path)
        try:
            text = p.read_text()
        except OSError as exc:
            raise ConfigError(f"cannot read config file {p}: {exc.strerror}") from None
        except UnicodeDecodeError as exc:
            raise ConfigError(f"config file {p} is not UTF-8 text: {exc.reason} at byte {exc.start}") from None
        try:
            loaded = safe_load_unique(text)
        except DuplicateKeyError as exc:
            raise ConfigError(f"config file {p}: key {exc.key!r} appears twice in one mapping, on lines "
                              f"{exc.first_line} and {exc.line}; keep one (YAML would silently use the last)") from None
        except yaml.YAMLError as exc:
            raise ConfigError(f"config file {p} is not valid YAML: {exc}") from None
        if loaded is None:
            loaded = {}
        if not isinstance(loaded, dict):
            raise ConfigError(f"config file {p} must hold a mapping of sections, got {type(loaded).__name__}")
        refuse_retired_keys(loaded, f"config file {p}")
        data = loaded
    if overrides:
        refuse_retired_keys(overrides, "configuration overrides")
        data = _merge(data, overrides)
    return from_dict(Config, data)


def _merge(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    out = dict(a)
    for k, v in b.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def config_template() -> str:
    """The full default configuration as commented YAML."""
    head = "# mercury-dem configuration (all keys optional; defaults shown)\n"
    return head + template(Config()).lstrip("\n") + "\n"


__all__ = ["Config", "load_config", "config_template", "to_dict", "ConfigError"]
