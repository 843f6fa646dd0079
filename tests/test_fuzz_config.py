"""Fuzzing the YAML configuration reader: any file gives a Config or ConfigError naming the key or the file.

Inputs: arbitrary YAML documents (a recursive strategy of dicts/lists/scalars, often
shaped like the real tree: known section and key names), damaged YAML text, and
random text. ``MERCURY_DEM_FUZZ_EXAMPLES`` raises the number of inputs (default 200, ~3 s).
"""

from __future__ import annotations

import dataclasses
import os
import re
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from mercury_dem.config import Config, ConfigError, load_config

SECTIONS = {f.name: [g.name for g in dataclasses.fields(getattr(Config(), f.name))] for f in dataclasses.fields(Config)}
NAMES = sorted(SECTIONS) + sorted({k for ks in SECTIONS.values() for k in ks})

scalars = st.one_of(st.none(), st.booleans(), st.integers(-(10**30), 10**30), st.floats(allow_nan=True),
                    st.text(max_size=10), st.sampled_from(NAMES))
keys = st.sampled_from(NAMES) | st.text(max_size=6) | st.integers(-3, 3) | st.booleans() | st.none()
documents = st.recursive(scalars, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(keys, inner, max_size=5),
                         max_leaves=20)


@st.composite
def shaped(draw: st.DrawFn) -> dict:
    """A tree shaped like the config: known sections and keys with arbitrary values."""
    out: dict = {}
    for sec in draw(st.lists(st.sampled_from(sorted(SECTIONS)), max_size=3, unique=True)):
        out[sec] = draw(st.dictionaries(st.sampled_from(SECTIONS[sec]), documents, max_size=4))
    return out


def _dump(doc: object) -> str:
    return yaml.safe_dump(doc, allow_unicode=True)


@st.composite
def config_text(draw: st.DrawFn) -> str:
    kind = draw(st.sampled_from(("doc", "shaped", "text", "cut")))
    if kind == "doc":
        return _dump(draw(documents))
    if kind == "shaped":
        return _dump(draw(shaped()))
    if kind == "text":
        return draw(st.text(max_size=80))
    text = _dump(draw(shaped()))
    return text[: draw(st.integers(0, len(text)))] + draw(st.sampled_from(("", ":", "- ", "{", "[", "&a", "*a", "!!python/object:os.system", "\t", "? ")))


@pytest.fixture(scope="module")
def fuzz_path() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="config_fuzz_") as d:
        yield Path(d) / "fuzzed-config.yaml"


@settings(max_examples=int(os.environ.get("MERCURY_DEM_FUZZ_EXAMPLES", "200")), deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(text=config_text())
@example(text="")
@example(text="match:\n  ratio: \udcff\n")  # was: UnicodeDecodeError
@example(text="x: &a [*a]\n")  # an alias of itself
@example(text="adjust:\n  held_images: &l [[*l]]\n")  # a self-containing list
@example(text="match: {ratio: .nan}\n")
def test_any_yaml_gives_config_or_config_error(fuzz_path: Path, text: str) -> None:
    fuzz_path.write_bytes(text.encode("utf-8", "surrogatepass"))
    try:
        cfg = load_config(fuzz_path)
    except ConfigError as exc:
        msg = str(exc)
        assert str(fuzz_path) in msg or re.search(r"config key '[^']*'", msg), msg
        return
    assert isinstance(cfg, Config)
