# mercury-dem: two commands on a fresh machine.
#   make demo  - set everything up, then run the main job on the synthetic default
#   make test  - set everything up, then run the test suite
# Both are idempotent: set-up is skipped when nothing it depends on changed.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
# Debian packages the project needs at run or test time (installed with apt when missing):
# SuiteSparse for CHOLMOD, gdal-bin for gdalinfo/gdal_grid checks, Chromium for the dashboard browser test,
# SLURM and munge for the one-node SLURM the batch-system test starts (tests/pipeline/test_slurm.py).
DEB_PACKAGES := libsuitesparse-dev gdal-bin chromium chromium-driver slurm-wlm munge
DEMO_DIR ?= demo_output

.PHONY: setup system-deps test test-fast test-slow lint demo clean bench-deps

setup: system-deps $(STAMP)

system-deps:
	@missing=""; for p in $(DEB_PACKAGES); do \
	  dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:$$missing"; \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO=sudo; \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq $$missing >/dev/null; \
	fi

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q -e '.[test,cluster,browser,lint]'
	@$(PY) -m pip install -q -e '.[cholmod]' 2>/dev/null \
	  && echo "scikit-sparse (CHOLMOD) installed" \
	  || echo "scikit-sparse not installed: the bundle adjustment uses its scipy fallback"
	$(PY) -m mercury_dem.pipeline.warm  # numba's kernel cache and the CRS cache: a first 'grid' starts warm
	touch $(STAMP)

# The benchmarks' outside anchors (Ceres through pycolmap); the project itself does not need them.
bench-deps: setup
	$(PY) -m pip install -q -e '.[anchors]'

test: setup
	$(PY) -m pytest

test-slow: setup
	$(PY) -m pytest -m slow

# The fast inner loop: everything but the whole-run tests, on both cores (pytest-xdist).
# Bytecode is cached under .pytest_cache/pycache even where PYTHONDONTWRITEBYTECODE is set (as in this project's
# shared sessions): without it every worker re-compiles the package and re-rewrites the asserts of ~200 test
# modules at each run (~6 s of CPU a worker). The prefix keeps the cache out of the (maybe shared) venv.
# --dist loadgroup: each test module (or group of modules sharing a session fixture) runs on one worker, so its
# fixtures are built once (tests/conftest.py, pytest_xdist_make_scheduler).
test-fast: setup
	PYTHONDONTWRITEBYTECODE= PYTHONPYCACHEPREFIX=$(CURDIR)/.pytest_cache/pycache $(PY) -m pytest -m "not integration" -n 2 --dist loadgroup

# ruff (with pydocstyle's numpy convention) and mypy on the package, configured in pyproject.toml.
lint: setup
	$(VENV)/bin/ruff check mercury_dem
	$(VENV)/bin/mypy

# The demo mission is generated once and reused; the run resumes when interrupted.
demo: setup
	@if [ -f $(DEMO_DIR)/mission/.complete ]; then echo "reusing the demo mission in $(DEMO_DIR)/mission"; \
	else $(VENV)/bin/mercury-dem synth $(DEMO_DIR)/mission --preset demo --overwrite --workers $$(nproc); fi
	$(VENV)/bin/mercury-dem info $(DEMO_DIR)/mission
	$(VENV)/bin/mercury-dem run $(DEMO_DIR)/mission --out $(DEMO_DIR)/run --config workflows/demo.yaml

clean:
	rm -rf $(VENV) $(DEMO_DIR) .pytest_cache
