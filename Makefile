# Two commands for a newcomer: `make demo` (figures from the synthetic field) and `make test`
# (lint and the whole suite on the pinned bpy, on every core: minutes). `make test-all` is CI's.
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
# Python 3.13 for Blender 5.1-5.2 (bpy 5.2.3): python3.13 on PATH, else pyenv's.
PYTHON313 ?= $(shell for p in python3.13 $$HOME/.pyenv/versions/3.13*/bin/python3.13; do \
	"$$p" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 13))' 2>/dev/null && { command -v "$$p" || echo "$$p"; } && break; done)
VENV := .venv
VENV42 := .venv-bpy42
VENV45 := .venv-bpy45
VENV52 := .venv-bpy52
BIN := $(VENV)/bin
DEMO_DIR := demo
# pytest-xdist workers of `make test` (auto: one per core).
JOBS ?= auto

.PHONY: help venv venv42 venv45 venv52 demo test test-all test-core test-bpy42 test-bpy45 test-bpy52 test-app lint format bench extension clean

help:
	@echo "make demo       - set up .venv, make the synthetic field, render its figures into $(DEMO_DIR)/"
	@echo "make test       - lint, then the whole suite (core and Blender tests) on bpy 5.0.1 with the pinned"
	@echo "                  libraries, on every core (JOBS=auto); one file: .venv/bin/python -m pytest tests/FILE.py"
	@echo "make test-all   - CI's: lint, the suite on bpy 5.0.1 (pinned libraries, numpy 1.26), bpy 4.2 (the"
	@echo "                  oldest supported ones), bpy 5.2.3 on Python 3.13 (the newest: numpy 2, OpenCV 5),"
	@echo "                  the Blender tests on bpy 4.5 LTS, then test-app"
	@echo "make test-app   - the extension zip in a real blender executable (Debian 13's, in a chroot, if"
	@echo "                  none is on PATH): install, Build Relief, render_views.py, the sidebar in a window"
	@echo "make bench      - run the benchmarks (ratios against named peers)"
	@echo "make extension  - build one Blender extension zip per platform and Python into dist/"
	@echo "make docs       - build the docs site into docs/_build/html (Sphinx, warnings as errors; .venv-docs)"

$(VENV)/.installed: requirements.txt requirements-dev.txt
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else "Python 3.11 is needed (Blender 4.2-5.0 and their bpy wheels are 3.11); set PYTHON=/path/to/python3.11")'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -r requirements-dev.txt
	@touch $@

# The declared minimum Blender with the oldest library versions pyproject.toml admits.
$(VENV42)/.installed: requirements-bpy42.txt
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else "Python 3.11 is needed for bpy 4.2; set PYTHON=/path/to/python3.11")'
	$(PYTHON) -m venv $(VENV42)
	$(VENV42)/bin/pip install -q --upgrade pip
	$(VENV42)/bin/pip install -q -r requirements-bpy42.txt
	@touch $@

# Blender 4.5 LTS with the pinned libraries, for the Blender tests.
$(VENV45)/.installed: requirements.txt requirements-bpy45.txt
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else "Python 3.11 is needed for bpy 4.5; set PYTHON=/path/to/python3.11")'
	$(PYTHON) -m venv $(VENV45)
	$(VENV45)/bin/pip install -q --upgrade pip
	$(VENV45)/bin/pip install -q -r requirements-bpy45.txt
	@touch $@

# Blender 5.1-5.2 LTS: Python 3.13, numpy 2, and the newest OpenCV, scikit-image and SciPy.
$(VENV52)/.installed: requirements-bpy52.txt
	@if [ -z "$(PYTHON313)" ]; then \
	  echo "Python 3.13 is needed for the tests on Blender 5.1-5.2 (bpy 5.2.3) and was not found."; \
	  echo "Install it (e.g. 'pyenv install 3.13', 'apt-get install python3.13-venv' on Debian 13,"; \
	  echo "or python.org) and put python3.13 on PATH, or run 'make test PYTHON313=/path/to/python3.13'."; \
	  exit 1; fi
	$(PYTHON313) -m venv $(VENV52)
	$(VENV52)/bin/pip install -q --upgrade pip
	$(VENV52)/bin/pip install -q -r requirements-bpy52.txt
	@touch $@

venv: $(VENV)/.installed
venv42: $(VENV42)/.installed
venv45: $(VENV45)/.installed
venv52: $(VENV52)/.installed

demo: venv
	$(BIN)/python -m cliff_terrain synthetic $(DEMO_DIR)/synthetic_field.png
	$(BIN)/python render_views.py $(DEMO_DIR)/synthetic_field.png --out $(DEMO_DIR)/synthetic_field_relief --overwrite
	@echo "Figures: $(DEMO_DIR)/synthetic_field_relief/"

lint: venv
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

format: venv
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

# The whole suite on the pinned bpy, in JOBS worker processes (pytest-xdist); each file's tests stay in one
# worker (--dist loadfile): the Blender tests of a file share its registered add-on and scene.
test-core: venv
	$(BIN)/python -m pytest -n $(JOBS) --dist loadfile

test-bpy42: venv42
	$(VENV42)/bin/python -m pytest

test-bpy45: venv45
	$(VENV45)/bin/python -m pytest -m blender

test-bpy52: venv52
	$(VENV52)/bin/python -m pytest

test: lint test-core

test-all: lint test-core test-bpy42 test-bpy45 test-bpy52 test-app

# The chroot of tools/test_app.sh needs root.
test-app: venv
	$(if $(filter 0,$(shell id -u)),,sudo) env PY=$(BIN)/python bash tools/test_app.sh

bench: venv
	$(BIN)/python bench/run_all.py

extension: venv
	$(BIN)/python tools/build_extension.py

clean:
	rm -rf dist wheels build .pytest_cache .ruff_cache

# The docs site (docs/, Sphinx + MyST + numpydoc) into docs/_build/html, warnings as errors, in a venv
# of its own: the core's pinned libraries (autodoc imports the core; never bpy) and the docs tools.
VENVDOCS := .venv-docs
.PHONY: docs venv-docs

$(VENVDOCS)/.installed: requirements.txt requirements-docs.txt
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else "Python 3.11 is needed for the docs (the core pinned as Blender 4.2-5.0 run it); set PYTHON=/path/to/python3.11")'
	$(PYTHON) -m venv $(VENVDOCS)
	$(VENVDOCS)/bin/pip install -q --upgrade pip
	$(VENVDOCS)/bin/pip install -q -r requirements-docs.txt
	@touch $@

venv-docs: $(VENVDOCS)/.installed

docs: venv-docs
	rm -rf docs/_build/html
	$(VENVDOCS)/bin/python -m sphinx -W --keep-going -q -b html docs docs/_build/html
	@echo "Docs: docs/_build/html/index.html"
