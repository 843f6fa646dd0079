"""The CLI called as main([...])."""

from __future__ import annotations

import json

import pytest
import yaml

from mercury_dem.cli import main
from mercury_dem.config import Config, load_config, to_dict


def test_help_lists_subcommands(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for cmd in ("config", "tiles"):
        assert cmd in out


def test_config_template_is_valid_yaml_and_the_defaults(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["config", "--template"]) == 0
    text = capsys.readouterr().out
    assert "# " in text  # commented
    assert yaml.safe_load(text) == to_dict(Config())


def test_bad_config_value_names_key_and_range(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text("match:\n  ratio: 7\n")
    assert main(["config", "--config", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert "match.ratio" in err and "range" in err
    cfg.write_text("tiling:\n  tile_sise_deg: 10\n")
    assert main(["tiles", "--config", str(cfg)]) == 2
    assert "tiling.tile_sise_deg" in capsys.readouterr().err


def test_config_file_overrides_defaults(tmp_path) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text("tiling:\n  tile_size_deg: 15\nadjust:\n  max_iterations: 7\n")
    c = load_config(cfg)
    assert c.tiling.tile_size_deg == 15.0 and c.adjust.max_iterations == 7
    assert c.match == Config().match


def test_tiles_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["tiles", "--json", "--tile-size", "15"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["tiles"] == 288 and len(s["regions"]) == 14
