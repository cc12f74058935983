"""Shared fixtures: the Mitsuba variant is set once per session; tiny scenes come from factory.py,
fake report run folders from fakes.py (test modules import builders from those two, never from
each other)."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture(scope="session", autouse=True)
def _variant():
    from framework.render.backend import set_variant
    set_variant("llvm_ad_rgb")


@pytest.fixture
def tiny_scene(tmp_path):
    from factory import make_tiny_scene
    return make_tiny_scene(tmp_path / "tiny")


@pytest.fixture
def fake_sweep(tmp_path) -> Path:
    """A sweep folder with 2 methods x 3 seeds of fake runs (fakes.make_fake_sweep)."""
    from fakes import make_fake_sweep
    return make_fake_sweep(tmp_path / "sweep")
