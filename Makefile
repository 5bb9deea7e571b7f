# Two commands for a newcomer: `make demo` (figures from the synthetic field) and `make test`.
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
VENV42 := .venv-bpy42
BIN := $(VENV)/bin
DEMO_DIR := demo

.PHONY: help venv venv42 demo test test-core test-blender42 lint format bench extension clean

help:
	@echo "make demo       - set up .venv, make the synthetic field, render its figures into $(DEMO_DIR)/"
	@echo "make test       - lint and run the whole test suite (bpy 5.0.1, then the Blender tests on bpy 4.2)"
	@echo "make bench      - run the benchmarks (ratios against named peers)"
	@echo "make extension  - build one Blender extension zip per platform into dist/"

$(VENV)/.installed: requirements.txt requirements-dev.txt
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else "Python 3.11 is needed (Blender 4.2-5.0 and the bpy wheels are 3.11); set PYTHON=/path/to/python3.11")'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -r requirements-dev.txt
	@touch $@

# A second environment with the declared minimum Blender, for the Blender tests only.
$(VENV42)/.installed: requirements.txt requirements-bpy42.txt
	$(PYTHON) -m venv $(VENV42)
	$(VENV42)/bin/pip install -q --upgrade pip
	$(VENV42)/bin/pip install -q -r requirements-bpy42.txt
	@touch $@

venv: $(VENV)/.installed
venv42: $(VENV42)/.installed

demo: venv
	$(BIN)/python -m cliff_terrain.synthetic $(DEMO_DIR)/synthetic_field.png
	$(BIN)/python render_views.py $(DEMO_DIR)/synthetic_field.png --out $(DEMO_DIR)/synthetic_field_relief --overwrite
	@echo "Figures: $(DEMO_DIR)/synthetic_field_relief/"

lint: venv
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

format: venv
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

test-core: venv
	$(BIN)/python -m pytest

test-blender42: venv42
	$(VENV42)/bin/python -m pytest -m blender

test: lint test-core test-blender42

bench: venv
	$(BIN)/python bench/run_all.py

extension: venv
	$(BIN)/python tools/build_extension.py

clean:
	rm -rf dist wheels build .pytest_cache .ruff_cache
