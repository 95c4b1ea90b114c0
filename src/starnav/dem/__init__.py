"""Lunar surface: DEMs, albedo maps and view-adapted meshes.

Public API (imported lazily; this module imports nothing heavy)::

    from starnav.dem import DemConfig, load_dem, load_albedo, view_mesh

    cfg = DemConfig(source="LDEM_16.LBL")        # or DemConfig() for the procedural Moon
    dem = load_dem(cfg)                           # DemGrid: heights [m] above 1737.4 km
    albedo = load_albedo(cfg)                     # AlbedoGrid or None
    mesh = view_mesh(dem, camera, r_cam_body_m, albedo, camera_to_body=R_cb)

* :mod:`starnav.dem.schema` - ``DemConfig`` (the ``moon.dem`` section), ``AlbedoConfig``,
  ``ProceduralDemConfig``, ``MeshConfig``.
* :mod:`starnav.dem.grid` - ``DemGrid``, ``AlbedoGrid``, selenographic <-> body-fixed.
* :mod:`starnav.dem.readers` - LOLA PDS3, GeoTIFF, SVS Moon kit, ``.npy``; albedo decodings.
* :mod:`starnav.dem.procedural` - the procedural Moon (craters, roughness, maria).
* :mod:`starnav.dem.mesh` - ``view_mesh``, the mesh cache (a scenario's mesh:
  ``starnav.simulate.frame_mesh``).
"""

from __future__ import annotations

from starnav._lazy import lazy_exports
from starnav.dem.schema import AlbedoConfig, DemConfig, MeshConfig, ProceduralDemConfig

_LAZY = {
    "DemGrid": "starnav.dem.grid",
    "AlbedoGrid": "starnav.dem.grid",
    "selenographic_to_body": "starnav.dem.grid",
    "body_to_selenographic": "starnav.dem.grid",
    "load_dem": "starnav.dem.load",
    "load_albedo": "starnav.dem.load",
    "read_dem": "starnav.dem.readers",
    "read_albedo": "starnav.dem.readers",
    "write_geotiff": "starnav.dem.readers",
    "dem_info": "starnav.dem.readers",
    "DemFileError": "starnav.dem.readers",
    "procedural_moon": "starnav.dem.procedural",
    "view_mesh": "starnav.dem.mesh",
    "save_mesh": "starnav.dem.mesh",
    "MeshOptions": "starnav.dem.mesh",
    "MeshCache": "starnav.dem.mesh",
    "MESH_CACHE": "starnav.dem.mesh",
}

__all__ = ["AlbedoConfig", "DemConfig", "MeshConfig", "ProceduralDemConfig", *_LAZY]
__getattr__, __dir__ = lazy_exports(__name__, _LAZY, eager=tuple(__all__))
