"""Shared helpers of the detector tests: small cameras and a configuration with every effect off."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from starnav.camera import Camera
from starnav.detector.schema import DetectorConfig


def small_camera(n: int = 64, **kw: Any) -> Camera:
    """The AA-STR optics on an ``n x n`` cut of the HAS2 (same pitch, focal length, f-number)."""
    return Camera.preset("aa-str", width=n, height=n, cx=(n - 1) / 2.0, cy=(n - 1) / 2.0, **kw)


def quiet_config(**sections: Any) -> DetectorConfig:
    """Every effect off (radiometry only, no cos^4), then ``sections`` merged on top."""
    base: dict[str, Any] = {
        "optics": {"radiometry": {"relative_illumination": False},
                   "aberration": {"enabled": False}, "distortion": {"enabled": False},
                   "stray_light": {"enabled": False}, "ghosts": {"enabled": False}},
        "smear": {"rolling_shutter": {"enabled": False}, "transfer": {"enabled": False}},
        "charge": {"prnu": {"enabled": False}, "dark_current": {"enabled": False},
                   "shot_noise": {"enabled": False}},
        "saturation": {"enabled": False},
        "signal": {"ipc": {"enabled": False}, "electrical_crosstalk": {"enabled": False},
                   "nonlinearity": {"enabled": False}, "read_noise": {"enabled": False}},
        "readout": {"timing": {"policy": "ignore"}},
    }

    def merge(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
        out = dict(a)
        for k, v in b.items():
            out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k),
                                                                               dict) else v
        return out

    return DetectorConfig.model_validate(merge(base, sections))


def lambert_disc(n: int, centre: tuple[float, float], radius: float, peak: float,
                 sun_dir: tuple[float, float, float] = (0.6, 0.0, 0.8)) -> np.ndarray:
    """Electron radiance of a Lambert sphere seen as a disc (numpy only, no renderer).

    ``L = peak * max(n . s, 0)`` with ``n`` the sphere normal under the pixel centre
    [e- s^-1 m^-2 sr^-1].
    """
    v, u = np.mgrid[0:n, 0:n].astype(float)
    x = (u - centre[0]) / radius
    y = (v - centre[1]) / radius
    r2 = x * x + y * y
    z = np.sqrt(np.clip(1.0 - r2, 0.0, None))
    s = np.asarray(sun_dir, float) / np.linalg.norm(sun_dir)
    mu0 = x * s[0] + y * s[1] + z * s[2]
    return np.where(r2 < 1.0, peak * np.clip(mu0, 0.0, None), 0.0).astype(np.float32)


@pytest.fixture
def cam64() -> Camera:
    return small_camera(64)
