"""Entry points from the configuration: :func:`load_dem` and :func:`load_albedo`.

``DemConfig.source`` is ``procedural`` or a file; ``DemConfig.albedo`` (an
:class:`~starnav.dem.schema.AlbedoConfig`) is ``None`` (keep ``moon.albedo``), ``procedural``
(the maria/highlands map of the same procedural world as the DEM's, seed and resolution from
``DemConfig.procedural``) or a map file. Results are kept in a small in-memory cache keyed by the
configuration and the file's size and modification time, so the frames of a run load a DEM
once.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from starnav.cache import BoundedCache
from starnav.config_base import format_validation_error
from starnav.data import packaged_path
from starnav.dem import procedural
from starnav.dem.grid import AlbedoGrid, DemGrid
from starnav.dem.procedural import procedural_moon
from starnav.dem.readers import read_albedo, read_dem
from starnav.dem.schema import AlbedoConfig, DemConfig

logger = logging.getLogger(__name__)

#: Grids kept in memory by :func:`load_dem` / :func:`load_albedo`.
LOAD_CACHE_SIZE = 4
_CACHE: BoundedCache[tuple[Any, ...], DemGrid | AlbedoGrid] = BoundedCache(LOAD_CACHE_SIZE)


def _file_stamp(source: str) -> tuple[Any, ...]:
    p = Path(source)
    try:
        st = p.stat()
        return (str(p.resolve()), st.st_size, st.st_mtime_ns)
    except OSError:
        return (source,)


#: Source names that stand for data shipped inside the package (``starnav.data``).
PACKAGED_SOURCES = {
    "dem": {"lola": "lola/LDEM_4.LBL"},
    "albedo": {"lroc": "albedo/lroc_wac_grey_2048.tif"},
}


def packaged_source(source: str, kind: str) -> str:
    """The file a source name stands for: a packaged data set (``lola``, ``lroc``) or the
    name itself (a path)."""
    rel = PACKAGED_SOURCES[kind].get(source)
    if rel is None:
        return source

    return str(packaged_path(rel))


def clear_cache() -> None:
    """Forget the grids loaded so far (and the procedural worlds)."""
    _CACHE.clear()
    procedural._CACHE.clear()


def as_dem_config(cfg: DemConfig | dict[str, Any] | None) -> DemConfig:
    """A :class:`DemConfig` from a config, a plain mapping (``moon.dem`` before it is typed) or
    ``None`` (the procedural default). Raises ``ConfigError`` naming the bad key."""
    if cfg is None:
        return DemConfig()
    if isinstance(cfg, DemConfig):
        return cfg
    try:
        return DemConfig.model_validate(cfg)
    except ValidationError as err:
        raise format_validation_error(err, prefix="moon.dem") from None


def load_dem(cfg: DemConfig | dict[str, Any] | None = None) -> DemGrid:
    """The DEM a configuration describes (file or procedural).

    Parameters
    ----------
    cfg : DemConfig or mapping or None
        ``None`` gives the default procedural Moon.

    Returns
    -------
    DemGrid
        Heights [m] above the reference sphere.
    """
    cfg = as_dem_config(cfg)
    if cfg.longitude_offset_deg:
        base = load_dem(cfg.model_copy(update={"longitude_offset_deg": 0.0}))
        return base.rotated_east(math.radians(cfg.longitude_offset_deg))  # type: ignore[return-value]
    if cfg.source == "procedural":
        radius = cfg.reference_radius_km * 1e3
        key = ("proc", cfg.procedural.model_dump_json(), radius, cfg.max_pixels_per_degree)

        def make() -> DemGrid:
            g = procedural_moon(cfg.procedural, radius).dem
            return g.resampled(cfg.max_pixels_per_degree) if cfg.max_pixels_per_degree else g

        return _CACHE.get_or_make(key, make)

    path = packaged_source(cfg.source, "dem")
    key = ("dem", _file_stamp(path), cfg.model_dump_json(exclude={"albedo", "mesh"}))
    return _CACHE.get_or_make(key, lambda: read_dem(path, cfg))


def load_albedo(cfg: DemConfig | AlbedoConfig | dict[str, Any] | None) -> AlbedoGrid | None:
    """The albedo map a configuration describes, or ``None`` if it names none.

    Parameters
    ----------
    cfg : DemConfig, AlbedoConfig, mapping or None
        A :class:`DemConfig` (its ``albedo`` and ``procedural`` sections are used) or an
        :class:`AlbedoConfig` alone (a procedural map then uses the default procedural world).

    Returns
    -------
    AlbedoGrid or None
        Values in 0..1 (``quantity`` says albedo or Hapke w).
    """
    if cfg is None:
        return None
    if isinstance(cfg, AlbedoConfig):
        dem_cfg, acfg = DemConfig(albedo=cfg), cfg
    else:
        dem_cfg = as_dem_config(cfg)
        acfg = dem_cfg.albedo
    if acfg is None:
        return None
    if dem_cfg.longitude_offset_deg:
        # the albedo turns with the terrain it belongs to
        base = load_albedo(dem_cfg.model_copy(update={"longitude_offset_deg": 0.0}))
        return None if base is None else base.rotated_east(  # type: ignore[return-value]
            math.radians(dem_cfg.longitude_offset_deg))
    if acfg.source == "procedural":
        radius = dem_cfg.reference_radius_km * 1e3
        key = ("proc-albedo", dem_cfg.procedural.model_dump_json(), radius,
               acfg.model_dump_json())

        def make() -> AlbedoGrid:
            g = procedural_moon(dem_cfg.procedural, radius).albedo
            quantity = acfg.resolved_quantity()
            if quantity == "relative" and acfg.normalize_mean is not None:
                quantity = "normal_albedo"
            if quantity != g.quantity or acfg.normalize_mean is not None:
                vals = g.values
                if acfg.normalize_mean is not None:
                    vals = vals * (acfg.normalize_mean / g.mean)
                g = AlbedoGrid(vals, extent=g.extent, quantity=quantity, source=g.source)
            if acfg.max_pixels_per_degree:
                g = g.resampled(acfg.max_pixels_per_degree)
            return g

        return _CACHE.get_or_make(key, make)

    path = packaged_source(acfg.source, "albedo")
    key = ("albedo", _file_stamp(path), acfg.model_dump_json())
    return _CACHE.get_or_make(key, lambda: read_albedo(path, acfg))
