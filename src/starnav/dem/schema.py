"""Scenario section ``moon.dem`` (owned by :mod:`starnav.dem`).

Where the terrain comes from (a file or the procedural Moon), how to decode it, where the
albedo comes from, and how finely to mesh it. Unit suffixes (``_km``, ``_deg``, ``_m``, ``_px``)
appear only here; the loaders convert to SI.

YAML::

    moon:
      shape: dem
      dem:
        source: data/LDEM_16.LBL        # or "procedural"
        max_pixels_per_degree: 8        # decimate at load (memory)
        albedo: {source: data/lroc_color_16bit.tif, decoding: linear, normalize_mean: 0.12}
        mesh: {edge_px: 1.0}
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from starnav.config_base import StrictModel
from starnav.fields import NonNegativeFloat, PositiveFloat, UnitInterval
from starnav.lunar_calibration import lunar_calibration


class ProceduralDemConfig(StrictModel):
    """The procedural Moon (see :mod:`starnav.dem.procedural` for the model and its sources).

    Crater densities are cumulative numbers of craters with diameter >= 1 km per km^2; the
    defaults follow the Neukum et al. (2001) chronology for ~3.9 Gyr highlands (0.03 km^-2) and
    ~3.5 Gyr maria (0.005 km^-2). Morphology laws are Pike (1977).
    """

    seed: Annotated[int, Field(ge=0)] = Field(
        1, description="seed of the procedural Moon (terrain and albedo; fixed per world)"
    )
    pixels_per_degree: Annotated[float, Field(gt=0, le=64, allow_inf_nan=False)] = Field(
        8.0, description="grid resolution [px/deg] (8 -> 3.79 km/px at the equator)"
    )
    crater_density_1km_km2: NonNegativeFloat = Field(
        0.03, description="highland N(D >= 1 km) [km^-2] (Neukum et al. 2001, ~3.9 Gyr)"
    )
    mare_crater_density_1km_km2: NonNegativeFloat = Field(
        0.005, description="mare N(D >= 1 km) [km^-2] (Neukum et al. 2001, ~3.5 Gyr)"
    )
    sfd_slope: Annotated[float, Field(gt=0.5, le=4.0)] = Field(
        2.0, description="cumulative size-frequency exponent b: N(>=D) ~ D^-b [-]"
    )
    crater_min_diameter_km: PositiveFloat | None = Field(
        None, description="smallest crater [km]; default 3 grid cells"
    )
    crater_max_diameter_km: PositiveFloat = Field(300.0, description="largest crater [km]")
    transition_diameter_km: PositiveFloat = Field(
        15.0, description="simple-to-complex transition diameter [km] (Pike 1977: 15 km)"
    )
    simple_depth_ratio: Annotated[float, Field(gt=0, le=0.5)] = Field(
        0.196, description="simple craters: rim-to-floor depth / diameter [-] (Pike 1977)"
    )
    complex_depth_coeff_km: PositiveFloat = Field(
        1.044, description="complex craters: depth = coeff * D^exp [km] (Pike 1977)"
    )
    complex_depth_exponent: Annotated[float, Field(gt=0, le=1.5)] = Field(
        0.301, description="complex craters: depth exponent [-] (Pike 1977)"
    )
    ejecta_exponent: Annotated[float, Field(gt=1.0, le=6.0)] = Field(
        3.0, description="ejecta thickness ~ (r/R)^-exponent [-] (McGetchin et al. 1973)"
    )
    roughness_rms_m: NonNegativeFloat = Field(
        120.0, description="RMS relief of the fractal roughness at the reference wavelength [m]"
    )
    roughness_ref_wavelength_km: PositiveFloat = Field(
        10.0, description="reference wavelength of roughness_rms_m [km]"
    )
    hurst_exponent: Annotated[float, Field(gt=0, lt=1.5)] = Field(
        0.9, description="Hurst exponent H: octave amplitude ~ wavelength^H [-]"
    )
    roughness_max_wavelength_km: PositiveFloat = Field(
        150.0, description="longest roughness wavelength [km]"
    )
    mare_fraction: UnitInterval = Field(
        0.16, description="fraction of the surface covered by maria [-] (Moon: ~16 %)"
    )
    mare_depth_m: NonNegativeFloat = Field(
        1500.0, description="depth of the mare plains below the surrounding terrain [m]"
    )
    highland_albedo: NonNegativeFloat = Field(0.14, description="highland albedo [-]")
    mare_albedo: NonNegativeFloat = Field(0.07, description="mare albedo [-]")
    albedo_noise: UnitInterval = Field(
        0.08, description="relative RMS of the albedo texture [-]"
    )
    fresh_ejecta_brightening: NonNegativeFloat = Field(
        0.04, description="albedo added on the ejecta of the youngest craters [-]"
    )


class AlbedoConfig(StrictModel):
    """Albedo source: a map file with its decoding, or the procedural maria/highlands map.

    Decodings (``decoding``), on raw pixel values ``DN``:

    * ``svs-8bit``: the NASA SVS CGI Moon Kit colour map: ``t = DN / 255`` over the
      ``domain``, gamma ``gamma``: ``r = ((lo + (hi - lo) t) / balance) ** gamma`` (gamma and
      colour balance applied before the range mapping, in the order the kit's page states;
      docs/facts.md section 3). The result is not a calibrated albedo: use ``normalize_mean``.
    * ``linear``: ``r = DN * scale + offset``; ``scale``/``offset`` default to the file's own
      (GDAL band scale/offset) or ``1 / (2**bits - 1)`` for unsigned integers.
    * ``reflectance``: values already in reflectance (float maps).
    * ``auto``: ``svs-8bit`` for 8-bit, ``linear`` for other integers, ``reflectance`` for floats.

    ``quantity`` says what the numbers are: ``normal_albedo`` (the physical normal albedo, which
    every photometric model converts to its own parameter), ``hapke_w`` (Hapke single-scattering
    albedo: the Hapke model only) or ``relative`` (a relative brightness pattern, e.g. a visual
    mosaic: its values are raised to ``contrast_exponent`` and scaled to the mean normal albedo
    given by ``normalize_mean``, else by ``moon.albedo``, else, for the packaged map, by the
    ROLO calibration). Several bands (RGB) are decoded separately and averaged unless ``band``
    picks one.

    ``source: lroc`` is the LROC WAC mosaic shipped with starnav (a linear relative grey map,
    :mod:`starnav.lunar_calibration`); its ``contrast_exponent`` defaults to the calibrated one.
    """

    source: str = Field("procedural", description="'procedural', 'lroc' (packaged LROC WAC "
                        "mosaic) or a map file path")
    format: Literal["auto", "geotiff", "npy"] = Field(
        "auto", description="file format of the map (auto: from the file name and contents)")
    decoding: Literal["auto", "svs-8bit", "linear", "reflectance"] = Field(
        "auto", description="how raw pixel values become reflectance: svs-8bit (NASA SVS Moon "
        "kit), linear (DN x scale + offset), reflectance (float maps), auto (by data type)")
    quantity: Literal["normal_albedo", "hapke_w", "relative"] | None = Field(
        None, description="what the values are; default 'relative' for 'lroc', else "
        "'normal_albedo'")
    contrast_exponent: PositiveFloat | None = Field(
        None, description="relative maps: values ** exponent before scaling; default the "
        "calibrated one for 'lroc', else 1 [-]")
    gamma: PositiveFloat = Field(2.8, description="svs-8bit gamma [-]")
    domain: tuple[float, float] = Field(
        (0.16, 0.40), description="svs-8bit encoded intensity range mapped to 0..255 [-]"
    )
    channel_balance: tuple[float, float, float] = Field(
        (0.935, 1.005, 1.04),
        description="svs-8bit, 3 bands: per-channel factors the kit applied after the gamma [-]",
    )
    scale: float | None = Field(None, description="linear decoding: value per DN [-]")
    offset: float | None = Field(None, description="linear decoding: value at DN = 0 [-]")
    band: Annotated[int, Field(ge=1)] | None = Field(
        None, description="1-based band to use; default the mean of all bands"
    )
    normalize_mean: PositiveFloat | None = Field(
        None, description="rescale so that the area-weighted mean equals this value [-]"
    )
    max_pixels_per_degree: PositiveFloat | None = Field(
        None, description="decimate (area average) at load to at most this resolution [px/deg]"
    )
    extent_deg: tuple[float, float, float, float] = Field(
        (-180.0, 180.0, -90.0, 90.0),
        description="(west, east, south, north) edges for files without georeferencing [deg]",
    )

    def resolved_quantity(self) -> str:
        """``quantity``, or its default for the source."""
        if self.quantity is not None:
            return self.quantity
        return "relative" if self.source == "lroc" else "normal_albedo"

    def resolved_contrast_exponent(self) -> float:
        """``contrast_exponent``, or its default (calibrated for ``lroc``, else 1)."""
        if self.contrast_exponent is not None:
            return float(self.contrast_exponent)
        if self.source == "lroc":
            return lunar_calibration().contrast_exponent
        return 1.0

    @model_validator(mode="after")
    def _contrast_for_relative(self) -> AlbedoConfig:
        if self.contrast_exponent is not None and self.resolved_quantity() != "relative":
            raise ValueError(f"contrast_exponent applies to quantity 'relative' maps only, got "
                             f"quantity {self.resolved_quantity()!r}")
        return self

    @field_validator("domain")
    @classmethod
    def _domain_order(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not (0.0 <= v[0] < v[1]):
            raise ValueError(f"domain must be (lo, hi) with 0 <= lo < hi, got {v}")
        return v

    @field_validator("extent_deg")
    @classmethod
    def _extent(cls, v: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        return _check_extent(v)


class MeshConfig(StrictModel):
    """View-adapted mesh knobs (see :mod:`starnav.dem.mesh` for their effect)."""

    edge_px: PositiveFloat = Field(
        1.0, description="target projected triangle edge [px] (tangential, and radial where "
        "the surface faces the camera)"
    )
    max_foreshortening: Annotated[float, Field(ge=1.0, le=64.0)] = Field(
        4.0, description="radial edges may grow up to this many pixel footprints where the "
        "surface is seen grazing [-]"
    )
    terrain_margin: bool = Field(
        True, description="extend the cap past the horizon for terrain above it"
    )
    frustum_margin_px: NonNegativeFloat = Field(
        16.0, description="margin around the field of view when culling [px]"
    )
    max_vertices: Annotated[int, Field(ge=1000)] = Field(
        4_000_000, description="vertex budget; edges are coarsened (with a warning) above it"
    )
    cache_size: Annotated[int, Field(ge=0)] = Field(4, description="meshes kept in memory")
    cache_quantum_px: NonNegativeFloat = Field(
        8.0, description="frames whose sub-camera point lies in the same cell of this many "
        "nadir pixels (and range in the same 1/8 octave) share one mesh, made conservative "
        "for the whole cell [px]; 0 = only identical geometry"
    )


class DetailConfig(StrictModel):
    """Fractal relief added below the DEM's posting where the mesh is finer than the DEM
    (see :mod:`starnav.dem.detail` for the model).

    Octaves of band-limited noise of wavelengths ``posting / 2^k`` continue the DEM's own
    structure function ``S(r) = S(posting) (r / posting)^H`` below the posting; nothing is added
    where the pixel footprint is coarser than the posting (the mesh is then unchanged).
    """

    enabled: bool = Field(True, description="refine meshes finer than the DEM's posting")
    hurst_exponent: Annotated[float, Field(gt=0, le=1.0, allow_inf_nan=False)] | Literal[
        "measured"] = Field(
        0.9, description="Hurst exponent H of the relief below the posting [-]; 'measured': "
        "from the DEM's structure function at 1 to 4 cells"
    )
    amplitude: Literal["regional", "global"] = Field(
        "regional", description="DEM roughness the detail continues: measured per window of "
        "roughness_window_km (rough highlands, smooth maria) or one global value"
    )
    roughness_window_km: PositiveFloat = Field(
        100.0, description="window over which the DEM's roughness is measured (regional) [km]"
    )
    seed: Annotated[int, Field(ge=0)] = Field(1, description="seed of the detail noise")
    min_wavelength_km: PositiveFloat = Field(
        0.05, description="shortest detail wavelength, whatever the pixel footprint [km]"
    )
    max_rms_slope_deg: Annotated[float, Field(gt=0, le=60.0, allow_inf_nan=False)] = Field(
        30.0, description="cap on the RMS slope of the detail, all octaves together [deg]"
    )


class DemConfig(StrictModel):
    """Lunar terrain for ``moon.shape: dem``.

    ``source`` is ``procedural`` (the default) or a file: LOLA LDEM PDS3 (``.LBL`` or ``.IMG``),
    NASA SVS Moon-kit TIFF (``ldem_*.tif``, float km or uint16 half-metres + 20 000), any
    GeoTIFF, or a NumPy ``.npy`` grid (heights in metres, north row first).

    Values are decoded as ``raw * scale + offset`` (from the file, or ``value_scale`` /
    ``value_offset_m`` when given), then, if they are radii (``vertical``: ``radius``, or
    ``auto`` with values above half the reference radius), the reference radius is subtracted.
    """

    source: str = Field("procedural", description="'procedural', 'lola' (the packaged LOLA "
                        "LDEM_4, 4 px/deg) or a DEM file path")
    format: Literal["auto", "pds3", "geotiff", "svs-geotiff", "npy"] = Field(
        "auto", description="file format of the DEM: pds3 (LOLA LDEM label), geotiff, svs-geotiff "
        "(NASA SVS Moon kit), npy (heights in m, north row first); auto: from the file name and "
        "contents")
    units: Literal["auto", "m", "km"] = Field(
        "auto", description="unit of the decoded values (auto: from the file or format)"
    )
    vertical: Literal["auto", "height", "radius"] = Field(
        "auto", description="decoded values are heights above the sphere or radii"
    )
    value_scale: float | None = Field(None, description="override the file's scale [unit/DN]")
    value_offset: float | None = Field(None, description="override the file's offset [unit]")
    reference_radius_km: PositiveFloat = Field(
        1737.4, description="reference sphere [km] (a PDS label's A_AXIS_RADIUS wins)"
    )
    longitude_offset_deg: float = Field(
        0.0, allow_inf_nan=False, description="turn the terrain and its albedo map eastwards "
        "about the pole by this angle [deg]: another stretch of real terrain under the same "
        "geometry (the terrain realisations of a Monte Carlo); 0 is the Moon as it is")
    extent_deg: tuple[float, float, float, float] = Field(
        (-180.0, 180.0, -90.0, 90.0),
        description="(west, east, south, north) edges for files without georeferencing [deg]",
    )
    max_pixels_per_degree: PositiveFloat | None = Field(
        None, description="decimate (area average) at load to at most this resolution [px/deg]"
    )
    procedural: ProceduralDemConfig = Field(
        default_factory=ProceduralDemConfig, description="the procedural Moon's craters, maria "
        "and roughness (source: procedural)")
    albedo: AlbedoConfig | None = Field(
        None, description="albedo map; None keeps moon.albedo (constant or its map)"
    )
    mesh: MeshConfig = Field(
        default_factory=MeshConfig, description="how finely the terrain is meshed for each frame")
    detail: DetailConfig = Field(
        default_factory=DetailConfig,
        description="fractal relief below the DEM's posting for close views (starnav.dem.detail)"
    )

    @field_validator("extent_deg")
    @classmethod
    def _extent(cls, v: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        return _check_extent(v)

    @model_validator(mode="after")
    def _source_not_empty(self) -> DemConfig:
        if not self.source.strip():
            raise ValueError("source must be 'procedural' or a file path, got an empty string")
        return self


def _check_extent(v: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    west, east, south, north = v
    if not (-90.0 <= south < north <= 90.0):
        raise ValueError(
            f"latitude edges (south, north) = ({south}, {north}) out of range: expected "
            "-90 <= south < north <= 90 deg"
        )
    if not (west < east <= west + 360.0):
        raise ValueError(
            f"longitude edges (west, east) = ({west}, {east}): expected west < east <= west + 360"
        )
    return v
