"""Fixtures of the DEM tests: small files of each format, written by the tests themselves."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture
def relief_dn() -> np.ndarray:
    """A 36 x 72 (5 deg) grid of int16 half-metre samples with a smooth, asymmetric relief."""
    lat = np.radians(87.5 - 5.0 * np.arange(36))[:, None]
    lon = np.radians(2.5 + 5.0 * np.arange(72))[None, :]
    h_m = 3000.0 * np.sin(lat) * np.cos(lon - 0.3) + 1500.0 * np.cos(3 * lon) * np.cos(lat)
    return np.round(h_m / 0.5).astype(np.int16)
