"""Scenario sections ``trajectory``, ``spacecraft`` and ``pointing`` (owned by
:mod:`starnav.scenes`).

Units are in the key names (``_km``, ``_deg``, ``_s``, ``_days``, ``_arcsec``, ``_px``) and are
converted to SI by :mod:`starnav.scenes.frames`. Epochs are ISO strings with an explicit time
scale (``UTC``, ``TT``, ``TDB`` or a trailing ``Z``).
"""

from __future__ import annotations

import datetime as _dt
import re
from pathlib import Path
from typing import Annotated, ClassVar, Literal

from pydantic import Field, field_validator, model_validator

from starnav.config_base import StrictModel
from starnav.fields import NonNegativeFloat, PositiveFloat

#: Default first epoch of the arc.
DEFAULT_EPOCH = "2027-03-01T00:00:00 TDB"
#: CR3BP length unit [km] (docs/facts.md s4), to express the halo amplitude in km.
_LU_KM = 384_400.0

_EPOCH_RE = re.compile(
    r"^\s*\d{4}-\d{2}-\d{2}(?:[T ]\d{2}:\d{2}(?::\d{2}(?:\.\d*)?)?)?\s*(?:Z|UTC|TT|TDB)\s*$",
    re.IGNORECASE,
)


class FlybyConfig(StrictModel):
    """Fly-by of a small body (``trajectory.source: flyby``; :mod:`starnav.scenes.flyby`).

    Closest approach (CA) is at ``trajectory.epoch``; frames every ``trajectory.cadence_s``
    from ``start_s`` to ``end_s`` relative to CA (at most ``trajectory.frames``).
    """

    v_inf_km_s: Annotated[float, Field(gt=0, le=100)] = Field(
        5.0, description="relative speed; the hyperbolic excess speed for dynamics=hyperbolic "
        "[km/s], at most 100 (a head-on encounter of two bodies at the Sun's escape speed at "
        "1 AU, 42.1 km/s each, is 84 km/s)")
    closest_approach_km: PositiveFloat = Field(20.0, description="CA distance from the body "
                                               "centre [km]")
    phase_at_ca_deg: Annotated[float, Field(ge=0, le=180)] = Field(
        45.0, description="Sun phase angle at CA (body->Sun vs body->spacecraft) [deg]")
    sun_azimuth_deg: float = Field(
        180.0, description="azimuth of the Sun about the CA direction from the CA velocity "
        "[deg]; 180: Sun on the approach side (approach phase 90 - phase_at_ca)")
    velocity_ra_deg: float = Field(0.0, description="CA velocity direction, J2000 RA [deg]")
    velocity_dec_deg: Annotated[float, Field(ge=-90, le=90)] = Field(
        0.0, description="CA velocity direction, J2000 Dec [deg]")
    ca_angle_deg: float = Field(0.0, description="CA direction about the velocity from the "
                                "projected J2000 pole (B-plane angle) [deg]")
    start_s: float = Field(-600.0, description="first frame relative to CA [s]")
    end_s: float = Field(600.0, description="last frame relative to CA [s]")
    sun_distance_au: Annotated[float, Field(ge=0.05, le=100)] = Field(
        1.0, description="body-Sun distance [AU]: 0.05 (inside Mercury's perihelion, 0.31) "
        "to 100 (beyond Eris' aphelion, 97.5)")
    dynamics: Literal["straight", "hyperbolic"] = Field(
        "straight", description="straight line (gravity neglected: micro-radian deflection or "
        "less for km-sized bodies) or the Kepler hyperbola of the body's GM")

    @model_validator(mode="after")
    def _span(self) -> FlybyConfig:
        if self.end_s < self.start_s:
            raise ValueError("end_s must not be before start_s")
        return self


#: Most samples of an arc (RK4 steps, frame or OEM epochs): 10^7 states of 6 float64 take
#: 0.5 GB, and the ephemeris model costs microseconds per step; a finer grid is a typo.
MAX_ARC_SAMPLES = 10_000_000
#: Bytes of one stored state (6 float64) and of one day [s], for the bound's message.
STATE_BYTES = 48
DAY_S = 86_400.0


class SpacecraftConfig(StrictModel):
    """The spacecraft as the truth dynamics see it (cannonball solar radiation pressure,
    :mod:`starnav.scenes.forces`). Defaults: a 12U CubeSat like LUMIO with its two deployed
    solar wings (assumptions of that order, not a datasheet): ~22 kg, ~0.6 m^2 facing the Sun,
    reflectivity coefficient 1.3 (mostly absorbing cells)."""

    mass_kg: PositiveFloat = Field(22.0, description="spacecraft mass [kg]")
    area_m2: PositiveFloat = Field(0.6, description="area facing the Sun [m^2]")
    reflectivity: Annotated[float, Field(ge=1.0, le=2.0)] = Field(
        1.3, description="SRP reflectivity coefficient C_r: 1 absorbing, 2 a face-on mirror [-]")


class TruthForcesConfig(StrictModel):
    """What the truth arc feels beyond the filter's Earth, Moon and Sun point masses
    (:class:`starnav.scenes.forces.TruthForceModel`); each a switch. The navigation filter
    keeps its own reduced model (``navigation.filter.dynamics``)."""

    planets: tuple[Literal["mercury", "venus", "mars", "jupiter", "saturn", "uranus",
                           "neptune"], ...] = Field(
        ("venus", "mars", "jupiter", "saturn"), description="DE421 planet barycentres added "
        "as point masses; empty: none (the filter's own model)")
    srp: bool = Field(True, description="cannonball solar radiation pressure of the "
                      "spacecraft section")
    eclipses: bool = Field(True, description="Earth and Moon shadows (conical, with "
                           "penumbra) on the solar radiation pressure")
    j2: bool = Field(True, description="Earth and Moon J2")


class TrajectoryConfig(StrictModel):
    """Observer trajectory and the frame epochs along it.

    ``source: halo`` builds the LUMIO-like L2 quasi-halo in the ephemeris point-mass model
    (:func:`starnav.scenes.trajectory.ephemeris_halo_arc`); ``source: oem`` reads a CCSDS OEM
    file (``oem_path``). Frames are taken every ``cadence_s`` from ``epoch + frame_offset_s``
    to the end of the arc (at most ``frames`` of them). ``source: flyby`` is a small-body
    fly-by (``flyby`` section, :class:`FlybyConfig`; ``epoch`` is the closest approach, the
    target a small body): the halo and OEM keys do not apply to it.
    """

    source: Literal["halo", "oem", "flyby"] = Field(
        "halo", description="LUMIO-like halo, an OEM file, or a small-body fly-by")
    epoch: str | None = Field(
        None, description=f"start of the arc, ISO with a time scale; None: {DEFAULT_EPOCH} "
        "for a halo, the first epoch of the file for an OEM")
    duration_days: PositiveFloat = Field(28.0, description="arc length [days]; for an OEM, "
                                         "the span used from epoch (clipped to the file)")
    cadence_s: PositiveFloat = Field(300.0, description="time between frames [s] (LUMIO: 5 min)")
    frame_offset_s: NonNegativeFloat = Field(0.0, description="first frame after epoch [s]")
    frames: Annotated[int, Field(ge=1)] | None = Field(
        None, description="number of frames; None: every cadence step of the arc")
    halo_z0_km: float = Field(
        -0.065 * _LU_KM, description="out-of-plane amplitude of the CR3BP L2 halo at its x-z "
        "plane crossing [km]; negative = southern family (docs/facts.md s4: -0.065 LU)")
    halo_phase_deg: Annotated[float, Field(ge=0, lt=360)] = Field(
        0.0, description="position on the halo at epoch, as a fraction of its period [deg]")
    step_s: PositiveFloat = Field(300.0, description="RK4 step of the ephemeris model [s]")
    shooting_segment_s: PositiveFloat = Field(43_200.0,
                                              description="multiple-shooting patch spacing [s]")
    range_min_km: NonNegativeFloat = Field(35_000.0, description="minimum Moon range [km]")
    range_max_km: PositiveFloat = Field(90_000.0, description="maximum Moon range [km]")
    oem_path: Path | None = Field(None, description="CCSDS OEM file for source=oem")
    moon_frame: Literal["PA", "ME"] = Field(
        "PA", description="Moon body-fixed frame: DE421 principal axes or mean-Earth/polar")
    forces: TruthForcesConfig = Field(
        default_factory=TruthForcesConfig, description="truth forces beyond the filter's "
        "point masses (halo arcs): planets, solar radiation pressure, eclipses, J2")
    flyby: FlybyConfig | None = Field(
        None, description="the fly-by for source=flyby (None: its defaults)")

    @field_validator("epoch", mode="before")
    @classmethod
    def _yaml_timestamp(cls, v: object) -> object:
        # YAML reads 2027-03-01T00:00:00Z as a UTC-aware datetime: keep its scale explicit
        if isinstance(v, _dt.datetime) and v.tzinfo is not None:
            utc = v.astimezone(_dt.UTC).replace(tzinfo=None)
            return utc.isoformat(timespec="microseconds") + " UTC"
        return v

    @field_validator("epoch")
    @classmethod
    def _epoch_has_scale(cls, v: str | None) -> str | None:
        if v is not None and not _EPOCH_RE.match(v):
            raise ValueError("an ISO date with an explicit time scale, e.g. "
                             f"'{DEFAULT_EPOCH}' (UTC, TT, TDB or a trailing Z)")
        return v

    @field_validator("halo_z0_km")
    @classmethod
    def _z0_range(cls, v: float) -> float:
        lo, hi = 0.01 * _LU_KM, 0.15 * _LU_KM
        if not (lo <= abs(v) <= hi):
            raise ValueError(f"|halo_z0_km| between {lo:.0f} and {hi:.0f} km")
        return v

    @model_validator(mode="after")
    def _consistent(self) -> TrajectoryConfig:
        if self.source == "oem" and self.oem_path is None:
            raise ValueError("trajectory.oem_path is required when source is 'oem'")
        if self.flyby is not None and self.source != "flyby":
            raise ValueError("trajectory.flyby is only read when source is 'flyby'")
        if self.range_min_km >= self.range_max_km:
            raise ValueError("range_min_km must be below range_max_km")
        if self.shooting_segment_s < self.step_s:
            raise ValueError("shooting_segment_s must be at least step_s")
        if self.source == "flyby":   # the fly-by's own span; no RK4 arc
            fb = self.flyby or FlybyConfig()
            steps, span, arc = [("cadence_s", self.cadence_s)], fb.end_s - fb.start_s, "fly-by"
        else:
            steps = [("step_s", self.step_s), ("cadence_s", self.cadence_s)]
            span, arc = self.duration_days * DAY_S, f"{self.duration_days:g}-day arc"
        for key, step in steps:
            if span / step > MAX_ARC_SAMPLES:
                raise ValueError(
                    f"{key} >= {span / MAX_ARC_SAMPLES:.3g} s over the {arc} ({key} = {step!r} "
                    f"gives {span / step:.3g} samples; at most {MAX_ARC_SAMPLES:.0e}, "
                    f"{STATE_BYTES} bytes each)")
        return self


class PointingConfig(StrictModel):
    """Moon-pointing attitude of the camera and its on-board knowledge.

    The boresight is turned so that the Moon centre lands on a pixel offset from the principal
    point: ``random`` draws the offset uniformly over the detector positions that keep the whole
    disc (exact limb ellipse) at least ``edge_margin_px`` inside the detector, within
    ``moon_offset_max_px`` of the principal point; ``fixed`` uses ``moon_offset_px``. The roll
    about the Moon line is uniform in [0, 360) deg (``roll: random``) or ``roll_deg``. The
    measured attitude is the true one rotated by a Gaussian error with the given 1-sigma per
    camera axis; the true attitude is never perturbed.
    """

    si_names: ClassVar[dict[str, str]] = {"roll_deg": "roll_angle"}

    moon_offset: Literal["random", "fixed"] = Field(
        "random", description="Moon-centre placement in the image (the paper varied it randomly)")
    moon_offset_px: tuple[float, float] = Field(
        (0.0, 0.0), description="Moon-centre offset (du, dv) from the principal point for "
        "moon_offset=fixed [px]")
    moon_offset_max_px: NonNegativeFloat = Field(
        512.0, description="largest random offset from the principal point [px]")
    edge_margin_px: NonNegativeFloat = Field(
        8.0, description="minimum distance between the limb and the detector edge [px]")
    roll: Literal["random", "fixed"] = Field("random", description="roll about the Moon line")
    roll_deg: float = Field(0.0, description="roll for roll=fixed [deg] (0: inertial north "
                            "towards the top of the image)")
    knowledge_cross_arcsec: NonNegativeFloat = Field(
        5.0, description="1-sigma attitude knowledge error about the camera x and y axes "
        "[arcsec] (assumed typical star-tracker value)")
    knowledge_roll_arcsec: NonNegativeFloat = Field(
        40.0, description="1-sigma attitude knowledge error about the boresight [arcsec] "
        "(assumed; star-tracker roll is several times worse than cross-boresight)")

    @property
    def knowledge_sigma(self) -> tuple[float, float, float]:
        """1-sigma attitude-knowledge error about the camera x, y, z (boresight) axes [rad]."""
        si = self.to_si()
        return (si.knowledge_cross, si.knowledge_cross, si.knowledge_roll)
