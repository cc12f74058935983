"""Shared fixtures: the Mitsuba variant is set once per session; tiny scenes come from factory.py."""
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
