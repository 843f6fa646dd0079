"""``mercury-dem synth`` and ``info`` from the command line, including bad input."""

from __future__ import annotations

import json

import pytest

from mercury_dem.cli import main


def test_synth_refuses_an_existing_out(tmp_path, capsys):
    out = tmp_path / "m"
    out.mkdir()
    assert main(["synth", str(out), "--preset", "tiny"]) == 2
    err = capsys.readouterr().err
    assert str(out) in err and "--overwrite" in err


def test_synth_names_allowed_presets_and_sigma_range(tmp_path, capsys):
    assert main(["synth", str(tmp_path / "a"), "--preset", "huge"]) == 2
    err = capsys.readouterr().err
    assert "synth.preset" in err and "'tiny'" in err and "'demo'" in err and "'large'" in err
    assert main(["synth", str(tmp_path / "b"), "--pointing-sigma-urad", "-3"]) == 2
    err = capsys.readouterr().err
    assert "synth.pointing_sigma_urad" in err and "range" in err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_info_summarises_and_maps(tiny_mission_path, tmp_path, capsys):
    png = tmp_path / "cov.png"
    assert main(["info", str(tiny_mission_path), "--json", "--coverage-map", str(png)]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["images"] == sum(s["images_by_instrument"].values())
    assert s["coverage"]["fraction_seen_3x"] > 0.8
    assert png.stat().st_size > 10_000
    assert main(["info", str(tmp_path / "none")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_synth_names_a_bad_image_selection(tmp_path, capsys):
    assert main(["synth", str(tmp_path / "a"), "--preset", "tiny", "--images", "30:10"]) == 2
    err = capsys.readouterr().err
    assert "30:10" in err and "38 images" in err
    with pytest.raises(SystemExit):  # argparse: --limit takes an integer
        main(["synth", str(tmp_path / "b"), "--preset", "tiny", "--limit", "x"])
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


@pytest.mark.integration  # a whole `synth` run (~2 s)
def test_info_says_a_mission_is_partial(tmp_path, capsys):
    out = tmp_path / "p"
    assert main(["synth", str(out), "--preset", "tiny", "--limit", "2", "--quiet"]) == 0
    capsys.readouterr()
    assert main(["info", str(out), "--coverage-map", str(tmp_path / "c.png")]) == 0
    text = capsys.readouterr().out
    assert "PARTIAL" in text and "2 of the 38 images" in text
