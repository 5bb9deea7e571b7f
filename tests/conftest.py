"""Shared fixtures: where the real UAV images live, and small helpers to reach them."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# CI clones the repo beside ../shared; the images are never copied into the project.
SHARED_UAV = REPO.parent / "shared" / "data" / "uav"


def uav_image(relative: str) -> Path:
    """Path of a shared UAV image, or skip the test with the reason when ../shared is absent."""
    path = SHARED_UAV / relative
    if not path.is_file():
        pytest.skip(f"shared UAV image {relative} not found under {SHARED_UAV} (../shared is absent)")
    return path


@pytest.fixture
def shared_uav() -> Path:
    """The folder of real UAV images (skips when ../shared is absent)."""
    if not SHARED_UAV.is_dir():
        pytest.skip(f"shared UAV images not found at {SHARED_UAV} (../shared is absent)")
    return SHARED_UAV


def pytest_sessionfinish(session, exitstatus):
    session.config.cliff_terrain_exitstatus = int(exitstatus)


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    # bpy 4.2 as a Python module segfaults while the interpreter shuts down, after every test has
    # passed and the summary is printed; leave before that teardown, with pytest's own exit code.
    status = getattr(config, "cliff_terrain_exitstatus", None)
    if "bpy" in sys.modules and status is not None:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
