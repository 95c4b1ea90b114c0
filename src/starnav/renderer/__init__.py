"""Spectral Mitsuba 3 renderer of lunar scenes in radiance units.

The only subpackage that imports Mitsuba and Dr.Jit, and only when a function needs them:
importing :mod:`starnav.renderer` is cheap.

It draws a target body's :class:`~starnav.bodies.model.TargetModel` (shape, photometry, albedo;
:mod:`starnav.bodies` is below the renderer, which imports it, never the reverse).

Modules: :mod:`~starnav.renderer.schema` (the ``render`` section),
:mod:`~starnav.renderer.render` (:class:`~starnav.renderer.render.MoonRenderer`,
:class:`~starnav.renderer.render.RenderSettings`), :mod:`~starnav.renderer.scene`,
:mod:`~starnav.renderer.bsdfs` (photometric plugins) and :mod:`~starnav.renderer.backend`
(variant choice, LLVM). A scenario becomes a renderer in :mod:`starnav.simulate`.
"""
