"""Spectral Mitsuba 3 renderer of lunar scenes in radiance units.

The only subpackage that imports Mitsuba and Dr.Jit, and only when a function needs them:
importing :mod:`starnav.renderer` is cheap.

Modules: :mod:`~starnav.renderer.schema` (the ``moon`` and ``render`` sections),
:mod:`~starnav.renderer.render` (:class:`~starnav.renderer.render.MoonRenderer`,
:class:`~starnav.renderer.render.MoonModel`, :class:`~starnav.renderer.render.RenderSettings`),
:mod:`~starnav.renderer.scene`, :mod:`~starnav.renderer.bsdfs` (photometric plugins),
:mod:`~starnav.renderer.dem_hook` (DEM meshes per view) and :mod:`~starnav.renderer.backend`
(variant choice, LLVM). A scenario becomes a renderer in :mod:`starnav.simulate`.
"""
