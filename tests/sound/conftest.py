"""Shared helpers of the sound tests: the synthetic click track (clicks.py, loaded by path as
the export tests load their readers)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

_spec = importlib.util.spec_from_file_location("sound_clicks", Path(__file__).with_name("clicks.py"))
_clicks = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_clicks)


@pytest.fixture
def clicks():
    """The click-track module: click_track(), CLICK_TIMES_S, lag_samples(), onsets()."""
    return _clicks
