"""Spectral Mitsuba 3 renderer of lunar scenes in radiance units.

The only subpackage that imports Mitsuba and Dr.Jit, and only when a function needs them:
importing :mod:`starnav.renderer` is cheap.

Public API: :func:`render_scenario`, :func:`renderer_from_scenario`, :func:`render_to_directory`,
:class:`~starnav.renderer.render.MoonRenderer`, :class:`~starnav.renderer.render.MoonModel`,
:class:`~starnav.renderer.render.RenderSettings`, and :mod:`starnav.renderer.backend`.
"""

from __future__ import annotations

from starnav.renderer.pipeline import (
    frame_geometries,
    render_scenario,
    render_to_directory,
    renderer_from_scenario,
)

__all__ = ["frame_geometries", "render_scenario", "render_to_directory",
           "renderer_from_scenario"]
