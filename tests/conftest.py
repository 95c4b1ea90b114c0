"""Shared test fixtures and tolerances (named constants, physical units)."""

from __future__ import annotations

import matplotlib
import pytest

matplotlib.use("Agg")

#: One pixel [px]; tolerances on image positions are expressed in it.
PIXEL = 1.0
#: Relative tolerance of radiometric closed-form checks (issue 2: 0.5 %).
RADIOMETRIC_RTOL = 5e-3


@pytest.fixture(scope="session")
def aa_str():
    from starnav.camera import Camera

    return Camera.preset("aa-str")
