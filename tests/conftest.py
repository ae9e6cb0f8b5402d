"""Shared fixtures: one small sensor so that jitted functions compile once per session."""

import pytest

from tactojax.sensor import gelslim


@pytest.fixture(scope="session")
def small_spec():
    """GelSlim at a quarter resolution: 60 x 80 px, 0.4 mm/px, same 32 x 24 mm field of view."""
    return gelslim(scale=0.25)
