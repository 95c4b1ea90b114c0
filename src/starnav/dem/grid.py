"""Equirectangular lunar grids: heights (:class:`DemGrid`) and albedo (:class:`AlbedoGrid`).

Conventions: selenographic, planetocentric, east-positive latitude and longitude in radians
inside (longitudes wrapped, returned in ``[-pi, pi)``); Moon body-fixed axes, metres, ``+x``
towards (0, 0), ``+z`` the north pole (:func:`selenographic_to_body`; LOLA's mean-Earth frame is
not corrected, < 1 km); ``values[i, j]`` the cell (pixel-is-area) centred at ``lat = north -
(i + 1/2) dlat``, ``lon = west + (j + 1/2) dlon``: row 0 north, column 0 west; a 360 deg grid
wraps, a regional one returns ``fill_value`` outside; heights in metres above the reference
sphere, float32. Sampling is bilinear between cell centres; :meth:`DemGrid.level` gives the
area-averaged mip level the mesher samples so that sparse vertices do not alias a fine DEM.

Index
-----
:class:`DemGrid`, :class:`AlbedoGrid`, :class:`EquirectangularGrid`,
:func:`selenographic_to_body`, :func:`body_to_selenographic`, :func:`wrap_longitude`,
:func:`area_resample`, :func:`area_resample_blocks`.
"""

from __future__ import annotations

import hashlib
import logging
import math
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from starnav.constants import MOON_RADIUS
from starnav.errors import ConfigError
from starnav.typing import FloatArray

logger = logging.getLogger(__name__)

#: Largest |height| accepted above/below the reference sphere [m]. The Moon's relief spans
#: about -9.1 to +10.8 km (LOLA); 100 km catches radii or kilometres passed as metres.
MAX_ABS_HEIGHT = 100_000.0
#: Tolerance on angular extents (rounding of labels and transforms) [rad]. LOLA's LDEM_4 label
#: gives MAP_SCALE = 7.58084 km/px, rounded: over 1440 samples the span is 2 pi + 1.3e-6 rad.
EXTENT_TOL = 1e-5
#: Full circle [rad].
TWO_PI = 2.0 * math.pi
HALF_PI = 0.5 * math.pi


# ------------------------------------------------------------------------- coordinates
def selenographic_to_body(lat: ArrayLike, lon: ArrayLike, height: ArrayLike = 0.0,
                          radius: float = MOON_RADIUS) -> FloatArray:
    """Moon body-fixed Cartesian position ``(..., 3)`` [m] of selenographic coordinates.

    Parameters
    ----------
    lat, lon : array_like
        Planetocentric latitude and east longitude [rad].
    height : array_like
        Height above the reference sphere [m].
    radius : float
        Reference sphere radius [m].
    """
    lat = np.asarray(lat, dtype=float)
    lon = np.asarray(lon, dtype=float)
    r = radius + np.asarray(height, dtype=float)
    cl = np.cos(lat)
    return np.stack(np.broadcast_arrays(r * cl * np.cos(lon), r * cl * np.sin(lon),
                                        r * np.sin(lat)), axis=-1)


def body_to_selenographic(xyz: ArrayLike, radius: float = MOON_RADIUS
                          ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Latitude [rad], east longitude in ``[-pi, pi)`` [rad] and height [m] of body-fixed points.

    Parameters
    ----------
    xyz : array_like, shape (..., 3)
        Moon body-fixed positions [m].
    radius : float
        Reference sphere radius [m].
    """
    p = np.asarray(xyz, dtype=float)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    rho = np.hypot(x, y)
    lat = np.arctan2(z, rho)
    lon = wrap_longitude(np.arctan2(y, x))
    return lat, lon, np.hypot(rho, z) - radius


def wrap_longitude(lon: ArrayLike) -> FloatArray:
    """Longitude wrapped into ``[-pi, pi)`` [rad]."""
    lon = np.asarray(lon, dtype=float)
    return (lon + math.pi) % TWO_PI - math.pi


# ------------------------------------------------------------------------- resampling
def _area_weights(n_src: int, n_dst: int) -> Any:
    """Sparse ``(n_dst, n_src)`` matrix averaging source cells into ``n_dst`` equal cells of the
    same span (area-weighted overlap)."""
    from scipy import sparse

    edges_src = np.arange(n_src + 1, dtype=float) / n_src
    edges_dst = np.arange(n_dst + 1, dtype=float) / n_dst
    rows, cols, vals = [], [], []
    j = 0
    for i in range(n_dst):
        lo, hi = edges_dst[i], edges_dst[i + 1]
        while edges_src[j + 1] <= lo:
            j += 1
        k = j
        while k < n_src and edges_src[k] < hi:
            ov = min(hi, edges_src[k + 1]) - max(lo, edges_src[k])
            if ov > 0:
                rows.append(i)
                cols.append(k)
                vals.append(ov * n_dst)
            k += 1
    return sparse.csr_matrix((vals, (rows, cols)), shape=(n_dst, n_src), dtype=np.float64)


def area_resample(values: NDArray[np.float32], shape: tuple[int, int]) -> NDArray[np.float32]:
    """Area-average a grid to a coarser ``shape`` with the same extent (float32 result)."""
    if tuple(shape) == values.shape:
        return values
    return area_resample_blocks(lambda r0, r1: values[r0:r1], values.shape, shape)


def area_resample_blocks(read_rows: Any, src_shape: tuple[int, int],
                         shape: tuple[int, int], block_cells: int = 1 << 22
                         ) -> NDArray[np.float32]:
    """Area-average a grid read in row blocks (``read_rows(r0, r1) -> (r1 - r0, n_lon)``) to
    ``shape``; memory is one block plus the result, whatever the source size.

    Separable: ``out = W_lat @ values @ W_lon^T`` with sparse overlap weights.
    """
    n_lat, n_lon = src_shape
    m_lat, m_lon = shape
    wl = _area_weights(n_lat, m_lat).tocsc()
    wc = _area_weights(n_lon, m_lon).T.tocsr()
    acc = np.zeros((m_lat, m_lon), dtype=np.float64)
    block = max(1, block_cells // max(n_lon, 1))
    for r0 in range(0, n_lat, block):
        r1 = min(n_lat, r0 + block)
        cols = np.asarray(read_rows(r0, r1), dtype=np.float64) @ wc  # (rows, m_lon)
        acc += np.asarray(wl[:, r0:r1] @ cols)
    return acc.astype(np.float32)


# ------------------------------------------------------------------------- grids
class EquirectangularGrid:
    """Base of :class:`DemGrid` and :class:`AlbedoGrid` (see the module docstring).

    Parameters
    ----------
    values : (n_lat, n_lon) array
        Cell values, row 0 northernmost, column 0 westernmost; stored as read-only float32.
    extent : (west, east, south, north)
        Cell-edge extent [rad]. Default: the whole globe with the western edge at -180 deg.
    source : str
        Where the grid comes from (file, ``procedural:seed=...``), for logs and cache keys.
    """

    #: Name of the values in messages.
    value_name: ClassVar[str] = "values"
    #: Field name prefix in error messages.
    field: ClassVar[str] = "grid"

    def __init__(self, values: ArrayLike,
                 extent: tuple[float, float, float, float] = (-math.pi, math.pi, -HALF_PI,
                                                               HALF_PI),
                 source: str = "") -> None:
        v = np.asarray(values)
        if v.ndim != 2 or v.shape[0] < 2 or v.shape[1] < 2:
            raise ConfigError(f"{self.field}.{self.value_name}", f"array of shape {v.shape}",
                              "a 2-D grid of at least 2 x 2 cells (rows = latitude)")
        v = np.ascontiguousarray(v, dtype=np.float32)
        west, east, south, north = (float(e) for e in extent)
        self._check_extent(west, east, south, north)
        if abs((east - west) - TWO_PI) <= EXTENT_TOL:
            east = west + TWO_PI  # a global grid: wrap exactly
        self._check_values(v, west, north, (east - west) / v.shape[1],
                           (north - south) / v.shape[0])
        v.flags.writeable = False
        self.values: NDArray[np.float32] = v
        self.west, self.east, self.south, self.north = west, east, south, north
        self.dlon = (east - west) / v.shape[1]
        self.dlat = (north - south) / v.shape[0]
        self.source = source
        self._levels: dict[int, EquirectangularGrid] = {0: self}
        self._uid: str | None = None
        self._range: tuple[float, float] | None = None

    # ------------------------------------------------------------------ validation
    def _check_extent(self, west: float, east: float, south: float, north: float) -> None:
        for name, val in (("west", west), ("east", east), ("south", south), ("north", north)):
            if not math.isfinite(val):
                raise ConfigError(f"{self.field}.extent.{name}", val, "a finite angle [rad]")
        for name, val in (("south", south), ("north", north)):
            if abs(val) > HALF_PI + EXTENT_TOL:
                raise ConfigError(f"{self.field}.extent.{name}",
                                  f"{math.degrees(val):.6g} deg",
                                  "a latitude within -90..90 deg")
        if not south < north:
            raise ConfigError(f"{self.field}.extent",
                              f"south {math.degrees(south):.6g} deg, north "
                              f"{math.degrees(north):.6g} deg", "south < north")
        if not (west < east <= west + TWO_PI + EXTENT_TOL):
            raise ConfigError(f"{self.field}.extent",
                              f"west {math.degrees(west):.6g} deg, east "
                              f"{math.degrees(east):.6g} deg",
                              "west < east <= west + 360 deg")

    def _check_values(self, v: NDArray[np.float32], west: float, north: float, dlon: float,
                      dlat: float) -> None:
        bad = ~np.isfinite(v)
        if bad.any():
            i, j = np.argwhere(bad)[0]
            lat = math.degrees(north - (i + 0.5) * dlat)
            lon = math.degrees(west + (j + 0.5) * dlon)
            raise ConfigError(
                f"{self.field}.{self.value_name}",
                f"{int(bad.sum())} NaN/inf cell(s), first at row {i}, column {j} "
                f"(lat {lat:.4f} deg, lon {lon:.4f} deg)",
                "finite values everywhere (fill the gaps or crop the grid)",
            )

    # ------------------------------------------------------------------ geometry
    @property
    def shape(self) -> tuple[int, int]:
        """``(n_lat, n_lon)``."""
        return self.values.shape  # type: ignore[return-value]

    @property
    def is_global_lon(self) -> bool:
        """True if the grid spans 360 deg of longitude (and wraps)."""
        return abs(self.east - self.west - TWO_PI) <= EXTENT_TOL

    @property
    def is_global_lat(self) -> bool:
        """True if the grid spans -90..90 deg of latitude."""
        return self.north >= HALF_PI - EXTENT_TOL and self.south <= -HALF_PI + EXTENT_TOL

    @property
    def pixels_per_degree(self) -> float:
        """Resolution along latitude [px/deg]."""
        return math.radians(1.0) / self.dlat

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(west, east, south, north)`` cell-edge extent [rad]."""
        return (self.west, self.east, self.south, self.north)

    def lat_centres(self) -> FloatArray:
        """Latitudes of the row centres, north first [rad]."""
        return self.north - (np.arange(self.shape[0]) + 0.5) * self.dlat

    def lon_centres(self) -> FloatArray:
        """Longitudes of the column centres, west first, as stored (not wrapped) [rad]."""
        return self.west + (np.arange(self.shape[1]) + 0.5) * self.dlon

    def cell_size(self, radius: float = MOON_RADIUS) -> float:
        """Cell size along a meridian [m] on a sphere of ``radius`` [m]."""
        return self.dlat * radius

    @property
    def value_range(self) -> tuple[float, float]:
        """``(min, max)`` of the values (cached)."""
        if self._range is None:
            self._range = (float(self.values.min()), float(self.values.max()))
        return self._range

    @property
    def fill_value(self) -> float:
        """Value returned outside a regional grid."""
        return 0.0

    @property
    def uid(self) -> str:
        """Content hash (values, extent, class), for cache keys."""
        if self._uid is None:
            h = hashlib.blake2b(digest_size=16)
            h.update(type(self).__name__.encode())
            h.update(np.asarray(self.extent, dtype=np.float64).tobytes())
            h.update(repr(self._identity_extra()).encode())
            h.update(np.asarray(self.values.shape, dtype=np.int64).tobytes())
            h.update(memoryview(self.values).cast("B"))
            self._uid = h.hexdigest()
        return self._uid

    def _identity_extra(self) -> Any:
        return ()

    # ------------------------------------------------------------------ sampling
    def sample(self, lat: ArrayLike, lon: ArrayLike) -> NDArray[np.float32]:
        """Bilinear value at selenographic ``lat`` [rad], ``lon`` [rad] (any range, wrapped).

        Raises
        ------
        ConfigError
            if a latitude lies outside -90..90 deg or is not finite.
        """
        lat = np.asarray(lat, dtype=float)
        lon = np.asarray(lon, dtype=float)
        if lat.size and not np.all(np.abs(lat) <= HALF_PI + 1e-9):
            bad = lat[~(np.abs(lat) <= HALF_PI + 1e-9)].ravel()[0]
            raise ConfigError("lat", f"{math.degrees(bad)!r} deg",
                              "a latitude within -90..90 deg")
        if lon.size and not np.all(np.isfinite(lon)):
            raise ConfigError("lon", "NaN/inf", "finite longitudes [rad]")
        lat, lon = np.broadcast_arrays(lat, lon)
        n_lat, n_lon = self.shape
        v = self.values
        # longitude: offset from the western edge in [0, 2 pi)
        dl = (lon - self.west) % TWO_PI
        x = dl / self.dlon - 0.5
        y = (self.north - lat) / self.dlat - 0.5
        outside = np.zeros(lat.shape, dtype=bool)
        if not self.is_global_lon:
            outside |= dl > (self.east - self.west) + 1e-12
            x = np.clip(x, 0.0, n_lon - 1.0)
        if not self.is_global_lat:
            outside |= (lat > self.north + 1e-12) | (lat < self.south - 1e-12)
        y = np.clip(y, 0.0, n_lat - 1.0)
        x0 = np.floor(x)
        fx = (x - x0).astype(np.float32)
        x0 = x0.astype(np.int64)
        if self.is_global_lon:
            x0 %= n_lon
            x1 = (x0 + 1) % n_lon
        else:
            x1 = np.minimum(x0 + 1, n_lon - 1)
        y0 = np.minimum(np.floor(y).astype(np.int64), n_lat - 1)
        fy = (y - y0).astype(np.float32)
        y1 = np.minimum(y0 + 1, n_lat - 1)
        top = v[y0, x0] * (1 - fx) + v[y0, x1] * fx
        bot = v[y1, x0] * (1 - fx) + v[y1, x1] * fx
        out = top * (1 - fy) + bot * fy
        if outside.any():
            out = np.where(outside, np.float32(self.fill_value), out)
        return out.astype(np.float32, copy=False)

    # ------------------------------------------------------------------ pyramid
    def _derived(self, values: NDArray[np.float32], source: str,
                 extent: tuple[float, float, float, float] | None = None) -> EquirectangularGrid:
        """A grid of the same type and extent (or ``extent``) with other values (subclasses
        add their fields)."""
        return type(self)(values, extent=self.extent if extent is None else extent,
                          source=source)

    def rotated_east(self, angle: float) -> EquirectangularGrid:
        """The same world turned eastwards about the pole by ``angle`` [rad]: the value that
        was at longitude ``lon`` is at ``lon + angle`` (exact: the grid's edges move, its
        cells do not). Only a grid that covers all longitudes can turn."""
        if angle == 0.0:
            return self
        if not self.is_global_lon:
            raise ConfigError(f"{self.field}.longitude_offset", f"{math.degrees(angle):.6g} deg",
                              "0 for a grid that does not cover all longitudes")
        return self._derived(self.values, f"{self.source}@east{math.degrees(angle):+.6g}deg",
                             (self.west + angle, self.east + angle, self.south, self.north))

    def level(self, k: int) -> EquirectangularGrid:
        """The grid area-averaged ``2**k`` times coarser (same extent); 0 is the grid itself.

        Levels are built on demand from the previous one and kept. A level never has fewer
        than 2 x 2 cells: :attr:`max_level` is the coarsest.
        """
        k = max(0, min(int(k), self.max_level))
        if k not in self._levels:
            prev = self.level(k - 1)
            shape = (max(2, prev.shape[0] // 2), max(2, prev.shape[1] // 2))
            vals = area_resample(prev.values, shape)
            g = prev._derived(vals, f"{self.source}#level{k}")
            self._levels[k] = g
            logger.debug("built level %d of %s: %s", k, self.source or "grid", shape)
        return self._levels[k]

    @property
    def max_level(self) -> int:
        """Coarsest pyramid level (at least 2 x 2 cells)."""
        return max(0, int(math.floor(math.log2(min(self.shape) / 2.0))))

    def level_for_spacing(self, spacing: float, radius: float = MOON_RADIUS) -> int:
        """Finest level whose cells are no larger than ``spacing`` [m] (at the equator)."""
        c0 = self.cell_size(radius)
        if spacing <= c0:
            return 0
        return min(self.max_level, int(math.floor(math.log2(spacing / c0))))

    def resampled(self, pixels_per_degree: float) -> EquirectangularGrid:
        """A copy area-averaged to at most ``pixels_per_degree`` [px/deg] (self if coarser)."""
        if pixels_per_degree >= self.pixels_per_degree:
            return self
        f = pixels_per_degree / self.pixels_per_degree
        shape = (max(2, round(self.shape[0] * f)), max(2, round(self.shape[1] * f)))
        return self._derived(area_resample(self.values, shape),
                             f"{self.source}@{pixels_per_degree:g}ppd")

    def __repr__(self) -> str:
        w, e, s, n = (math.degrees(a) for a in self.extent)
        return (f"{type(self).__name__}({self.shape[0]} x {self.shape[1]}, "
                f"{self.pixels_per_degree:.4g} px/deg, lon {w:.6g}..{e:.6g}, lat {s:.6g}..{n:.6g}"
                f", source={self.source!r})")


class DemGrid(EquirectangularGrid):
    """Heights above a reference sphere on an equirectangular grid.

    Parameters
    ----------
    heights : (n_lat, n_lon) array
        Heights above the reference sphere [m], row 0 northernmost.
    extent : (west, east, south, north)
        Cell-edge extent [rad]; default global, western edge at -180 deg.
    reference_radius : float
        Radius of the reference sphere [m] (LOLA: 1 737 400 m).
    source : str
        Provenance, for logs and cache keys.

    Raises
    ------
    ConfigError
        for NaN/inf heights, |height| above :data:`MAX_ABS_HEIGHT`, latitudes outside
        -90..90 deg, or an inconsistent extent; the message names the field and the value.
    """

    value_name = "heights"
    field = "dem"

    def __init__(self, heights: ArrayLike,
                 extent: tuple[float, float, float, float] = (-math.pi, math.pi, -HALF_PI,
                                                               HALF_PI),
                 reference_radius: float = MOON_RADIUS, source: str = "") -> None:
        if not (math.isfinite(reference_radius) and reference_radius > 0):
            raise ConfigError("dem.reference_radius", reference_radius, "a radius > 0 m")
        self.reference_radius = float(reference_radius)
        super().__init__(heights, extent=extent, source=source)

    def _check_values(self, v: NDArray[np.float32], west: float, north: float, dlon: float,
                      dlat: float) -> None:
        super()._check_values(v, west, north, dlon, dlat)
        big = float(np.max(np.abs(v)))
        if big > MAX_ABS_HEIGHT:
            raise ConfigError(
                "dem.heights", f"|height| up to {big:.6g} m",
                f"heights within +-{MAX_ABS_HEIGHT / 1e3:.0f} km of the reference sphere "
                "(are these radii, or kilometres read as metres?)",
            )

    def _identity_extra(self) -> Any:
        return (self.reference_radius,)

    def _derived(self, values: NDArray[np.float32], source: str,
                 extent: tuple[float, float, float, float] | None = None) -> DemGrid:
        return DemGrid(values, extent=self.extent if extent is None else extent,
                       reference_radius=self.reference_radius, source=source)

    @property
    def heights(self) -> NDArray[np.float32]:
        """Heights above the reference sphere [m] (read-only float32 view)."""
        return self.values

    @property
    def height_range(self) -> tuple[float, float]:
        """``(min, max)`` height [m]."""
        return self.value_range

    def height(self, lat: ArrayLike, lon: ArrayLike) -> NDArray[np.float32]:
        """Bilinear height [m] at ``lat``, ``lon`` [rad]."""
        return self.sample(lat, lon)

    def surface_point(self, lat: ArrayLike, lon: ArrayLike) -> FloatArray:
        """Body-fixed position ``(..., 3)`` [m] of the terrain at ``lat``, ``lon`` [rad]."""
        return selenographic_to_body(lat, lon, self.sample(lat, lon), self.reference_radius)

    def level(self, k: int) -> DemGrid:  # narrow the return type
        return super().level(k)  # type: ignore[return-value]

    def resampled(self, pixels_per_degree: float) -> DemGrid:
        return super().resampled(pixels_per_degree)  # type: ignore[return-value]

    @classmethod
    def zeros(cls, pixels_per_degree: float = 1.0, radius: float = MOON_RADIUS) -> DemGrid:
        """A global zero-height grid (the reference sphere itself)."""
        n_lat = max(2, round(180 * pixels_per_degree))
        return cls(np.zeros((n_lat, 2 * n_lat), np.float32), reference_radius=radius,
                   source=f"zeros@{pixels_per_degree:g}ppd")


class AlbedoGrid(EquirectangularGrid):
    """Albedo on an equirectangular grid.

    Parameters
    ----------
    albedo : (n_lat, n_lon) array
        Values in ``[0, 1]`` [-], row 0 northernmost.
    extent : (west, east, south, north)
        Cell-edge extent [rad].
    quantity : {'normal_albedo', 'hapke_w', 'relative'}
        What the values are: the physical normal albedo, the Hapke single-scattering albedo
        ``w``, or a relative brightness pattern still to be scaled
        (:class:`~starnav.dem.schema.AlbedoConfig`).
    source : str
        Provenance.
    """

    value_name = "albedo"
    field = "albedo"
    QUANTITIES: ClassVar[tuple[str, ...]] = ("normal_albedo", "hapke_w", "relative")

    def __init__(self, albedo: ArrayLike,
                 extent: tuple[float, float, float, float] = (-math.pi, math.pi, -HALF_PI,
                                                               HALF_PI),
                 quantity: str = "normal_albedo", source: str = "") -> None:
        if quantity not in self.QUANTITIES:
            raise ConfigError("albedo.quantity", quantity, f"one of {', '.join(self.QUANTITIES)}")
        self.quantity = quantity
        super().__init__(albedo, extent=extent, source=source)
        self._mean: float | None = None

    def _check_values(self, v: NDArray[np.float32], west: float, north: float, dlon: float,
                      dlat: float) -> None:
        super()._check_values(v, west, north, dlon, dlat)
        lo, hi = float(v.min()), float(v.max())
        if lo < 0.0 or hi > 1.0:
            raise ConfigError("albedo.values", f"range {lo:.6g}..{hi:.6g}",
                              "decoded albedo within 0..1 (check the decoding, scale, offset)")

    def _identity_extra(self) -> Any:
        return (self.quantity,)

    def _derived(self, values: NDArray[np.float32], source: str,
                 extent: tuple[float, float, float, float] | None = None) -> AlbedoGrid:
        return AlbedoGrid(values, extent=self.extent if extent is None else extent,
                          quantity=self.quantity, source=source)

    @property
    def fill_value(self) -> float:
        """Outside a regional map: its area-weighted mean."""
        return self.mean

    @property
    def mean(self) -> float:
        """Area-weighted (cos latitude) mean of the map [-]."""
        if self._mean is None:
            w = np.cos(self.lat_centres())
            self._mean = float(np.average(self.values.mean(axis=1, dtype=np.float64), weights=w))
        return self._mean

    def level(self, k: int) -> AlbedoGrid:
        return super().level(k)  # type: ignore[return-value]

    def resampled(self, pixels_per_degree: float) -> AlbedoGrid:
        return super().resampled(pixels_per_degree)  # type: ignore[return-value]
