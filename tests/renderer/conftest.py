"""Renderer test helpers: small, fast scenes built directly from the library."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.bodies.model import TargetModel
from starnav.camera import Camera
from starnav.geometry import static_geometry
from starnav.renderer.render import MoonRenderer, RenderSettings
from starnav.spectra import sensor_response, solar_spectrum

LLVM_FIRST = ("llvm_ad_spectral", "scalar_spectral")


def require_jit(ran_jit: bool, what: str) -> None:
    """Guard of a check that only a JIT variant can make (the fused loop, the adaptive
    render, kernel caching); ``ran_jit``: whether the renderer took the JIT path. Where this
    machine has no libLLVM >= 16 the renderer falls back to ``scalar_spectral`` as it must,
    and the check is skipped (CI installs libllvm19, so it runs there); where it has one, a
    fallback is itself a fault and fails."""
    from starnav.renderer import backend

    if ran_jit:
        return
    llvm = backend.find_llvm()
    if llvm is not None:
        pytest.fail(f"{what}: libLLVM {llvm.major} at {llvm.path}, but the renderer fell "
                    "back to scalar_spectral")
    pytest.skip(f"{what}: no libLLVM >= 16 on this machine (CI installs libllvm19)")


def make_renderer(camera: Camera | None = None, spp: int = 16, variants=LLVM_FIRST, **moon):
    camera = camera or Camera.preset("aa-str")
    return MoonRenderer(camera, sensor_response(), solar_spectrum(), TargetModel(**moon),
                        RenderSettings(spp=spp, variants=tuple(variants)))


def exact_solid_angles(camera: Camera) -> np.ndarray:
    """Solid angle of every pixel of the pinhole [sr] (cos^3 of the off-axis angle)."""
    u, v = camera.pixel_grid()
    x = (u - camera.cx) / camera.fx
    y = (v - camera.cy) / camera.fy
    return camera.pixel_solid_angle / (1 + x * x + y * y) ** 1.5


@pytest.fixture(scope="module")
def geom60(aa_str):
    """AA-STR at 60 000 km, phase 30 deg, Moon off-centre (the paper varies its place)."""
    return static_geometry(aa_str, 6.0e7, math.radians(30.0), (100.0, -50.0))
