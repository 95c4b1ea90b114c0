"""Ready-made studies: the paper's exposure study and the demo, plus the paper's numbers.

:data:`PAPER_CASES` holds the results of the STAR Nav paper (:data:`PAPER_CITATION`) for its
four exposure scenarios, and the criteria the sweep report judges a measured point by.
:data:`PRESETS` are sweep presets by name (``starnav sweep --preset NAME``): a resolved
scenario dict and a grid.

``exposure-study``
    The paper's four exposures (200, 7.7, 0.18 and 0.015 ms) on the AA-STR, the real Moon
    (the defaults) along a one-day LUMIO-like halo arc at 60 000-80 000 km, an image every
    30 minutes, the Moon at random in the field, the paper's pixel-accuracy algorithm
    (segments only) with Gauss-Markov biases in the EKF; 5 Monte Carlo runs per exposure. The
    stars are drawn, so the report also gives the attitude side (the fixes keep the paper's
    assumed attitude; ``--set navigation.attitude.source=stars`` uses the tracker's own).

Example
-------
>>> from starnav.batch.presets import exposure_study_scenario, get_preset
>>> sc = exposure_study_scenario()        # for `starnav init --preset exposure-study`
>>> get_preset("exposure-study").grid[0].split("=")[0]
'detector.exposure_time_s+detector.readout.segments.thresholds_dn'
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from starnav.config import scenario_from_dict, scenario_to_dict
from starnav.data import packaged_path
from starnav.registry import Registry

#: Where the paper's numbers come from: the paper itself and the page of this repository that
#: tabulates them against the toolkit.
PAPER_CITATION = ("Panicucci et al., \"What if star trackers were navigation cameras?\" (STAR "
                  "Nav study), sections \"Validation of rendering pipeline and implications\" "
                  "and the MIL/PIL/HIL results; tabulated in docs/sweep.md, \"The paper's "
                  "exposure study\"")

#: The paper's four exposure times [s] (seed paper, "Validation of rendering pipeline").
PAPER_EXPOSURES_S: tuple[float, ...] = (0.2, 7.7e-3, 1.8e-4, 1.5e-5)


@dataclass(frozen=True)
class PaperCase:
    """One exposure scenario of the paper and how a measured point is judged against it.

    Attributes
    ----------
    exposure_time : float
    name : str
    paper_limb, paper_navigation : str
        What the paper reports for the limb-point error and for navigation.
    limb_ok : callable
        ``limb_ok(bias_px, std_px) -> bool``: the measured limb agrees with the paper.
    navigation_ok : callable
        ``navigation_ok(row) -> bool`` on the point's median row.
    criteria : str
        The criteria in words (printed in the report).
    """

    exposure_time: float
    name: str
    paper_limb: str
    paper_navigation: str
    limb_ok: Callable[[float, float], bool]
    navigation_ok: Callable[[dict[str, Any]], bool]
    criteria: str


def _f(row: dict[str, Any], key: str) -> float:
    v = row.get(key)
    return float(v) if v is not None else math.nan


#: Mean 6-state NEES above which a filter is not to be trusted: 3 x its expected value.
NEES_UNTRUSTED = 18.0


def _no_navigation(row: dict[str, Any]) -> bool:
    """No useful navigation: few fixes, a large final error, or a filter whose covariance does
    not describe its error (the bias states absorb anything, so the error alone can look
    small while the estimate is not trustworthy)."""
    frames = max(_f(row, "frames"), 1.0)
    err = _f(row, "final_position_error_pct_range")
    nees = _f(row, "nees_mean")
    return (_f(row, "fixes") / frames < 0.5 or not (err < 5.0)
            or not (nees < NEES_UNTRUSTED))


PAPER_CASES: tuple[PaperCase, ...] = (
    PaperCase(0.2, "200 ms (unmodified tracker)", "severe saturation and blooming",
              "no useful navigation",
              lambda b, s: not (abs(b) < 2.5),
              _no_navigation,
              "limb: |bias| >= 2.5 px (or no limb); navigation: fixes in < 50 % of frames, "
              "final position error >= 5 % of range, or an inconsistent filter (mean NEES of "
              "the 6 states >= 18, three times its expected value)"),
    PaperCase(7.7e-3, "7.7 ms (HIL, fictitious)", "~5 px bias (saturation near the limb)",
              "< 1 % in all state components",
              lambda b, s: 2.5 <= b <= 10.0,
              lambda r: _f(r, "final_position_error_pct_range") < 1.0
              and _f(r, "final_velocity_error_pct_speed") < 1.0,
              "limb: bias in [2.5, 10] px; navigation: final position and velocity errors "
              "< 1 % of range and speed"),
    PaperCase(1.8e-4, "0.18 ms (firmware limit)",
              "pixel level (\"extremely similar\" to 0.015 ms)",
              "like 0.015 ms (not shown in the paper)",
              lambda b, s: abs(b) < 1.0,
              lambda r: _f(r, "final_position_error_pct_range") < 0.5
              and _f(r, "final_velocity_error_pct_speed") < 0.5,
              "limb: |bias| < 1 px; navigation: final errors < 0.5 %"),
    PaperCase(1.5e-5, "0.015 ms (HIL, well exposed)", "no bias, pixel-level accuracy",
              "< 0.5 % in all state components",
              lambda b, s: abs(b) < 1.0,
              lambda r: _f(r, "final_position_error_pct_range") < 0.5
              and _f(r, "final_velocity_error_pct_speed") < 0.5,
              "limb: |bias| < 1 px; navigation: final position and velocity errors < 0.5 % "
              "of range and speed"),
)

#: The paper's model-in-the-loop result on saturated synthetic images (exposure not stated).
PAPER_MIL_SATURATED = ("MIL, saturated synthetic images: ~10 px limb bias; navigation errors "
                       "< 2000 km and < 50 m/s (~5 %)")


def paper_case(exposure_time: float, rel_tol: float = 0.01) -> PaperCase | None:
    """The paper case of ``exposure_time`` [s] (within ``rel_tol``), or None."""
    for c in PAPER_CASES:
        if math.isclose(c.exposure_time, exposure_time, rel_tol=rel_tol):
            return c
    return None


# ============================================================================ scenarios
def _resolved(partial: dict[str, Any]) -> dict[str, Any]:
    return scenario_to_dict(scenario_from_dict(partial))


#: The exposure study's scenario, as the keys that differ from the defaults.
EXPOSURE_STUDY: dict[str, Any] = {
    "camera": {"preset": "aa-str"},
    # the moon: the default real Moon (LOLA LDEM_4, LROC albedo, ROLO-calibrated Hapke)
    "trajectory": {"source": "halo", "duration_days": 1.0, "cadence_s": 1800.0},
    "pointing": {"moon_offset": "random", "moon_offset_max_px": 300.0},
    "render": {"spp": 16, "aovs": False},
    "detector": {"exposure_time_s": 1.5e-5},
    # the stars in the frames: the attitude side of the trade-off (docs/stars.md)
    "stars": {"enabled": True},
    "navigation": {
        "refine": {"enabled": False},
        "ransac": {"model": "circle", "threshold_px": 2.0},
        "fix": {"attitude_sigma_arcsec": None},
        "filter": {"bias_model": "range-scale+additive", "range_scale_sigma": 0.02,
                   "bias_sigma_km": 50.0,
                   "bias_tau_days": 2.0, "initial_position_sigma_km": 100.0,
                   "initial_velocity_sigma_m_s": 1.0},
        "runs": 5,
    },
}

#: Segment threshold of each exposure [DN]: the paper tuned its image processing to each
#: scenario; at and above 0.18 ms the Moon saturates and the stray-light halo and the ghost
#: exceed the default 200 DN, so the saturated cases read segments at half scale (2048 DN).
PAPER_THRESHOLDS_DN: tuple[int, ...] = (2048, 2048, 2048, 200)

EXPOSURE_STUDY_GRID: tuple[str, ...] = (
    "detector.exposure_time_s+detector.readout.segments.thresholds_dn="
    + ",".join(f"[{t!r},[{th}]]" for t, th in zip(PAPER_EXPOSURES_S, PAPER_THRESHOLDS_DN,
                                                  strict=True)),)


def exposure_study_scenario() -> dict[str, Any]:
    """The complete scenario of the paper's exposure study (for ``starnav init --preset
    exposure-study``); run it with ``starnav sweep FILE --preset exposure-study --out DIR``."""
    return _resolved(EXPOSURE_STUDY)


def exposure_study_header() -> str:
    """Comment lines to put above :func:`exposure_study_scenario` in a YAML file."""
    return (
        "# starnav exposure study (the STAR Nav paper's four scenarios: 200 ms, 7.7 ms,\n"
        "# 0.18 ms, 0.015 ms). The grid is not part of the scenario; run:\n"
        "#   starnav sweep exposure-study.yaml --preset exposure-study --out out/exposure-study\n"
        "# or give it explicitly:\n"
        f"#   starnav sweep exposure-study.yaml --grid {EXPOSURE_STUDY_GRID[0]} --runs 5 "
        "--out DIR\n"
        "# The report compares the results with the paper (Panicucci et al., \"What if star "
        "trackers were navigation cameras?\"; docs/sweep.md).\n")


def tuned_filter(exposure_time: float) -> dict[str, Any]:
    """The EKF bias states tuned for ``exposure_time`` on calibration arcs
    (``starnav/data/navigation/bias_tuning.json``, written by ``tools/tune_bias_states.py``;
    never on the demo's own arc): the ``navigation.filter`` keys, or ``bias_model: none`` for
    an exposure that was not tuned."""
    doc = json.loads(packaged_path("navigation/bias_tuning.json").read_text())
    for key, v in doc["exposures"].items():
        if math.isclose(float(key), exposure_time, rel_tol=1e-6):
            return {k: v[k] for k in ("bias_model", "range_scale_sigma", "bias_sigma_km",
                                      "bias_tau_days", "accel_psd_m2_s3") if k in v}
    return {"bias_model": "none"}


#: The demo's scenario (``make demo``): see :mod:`starnav.batch.mainjob`.
DEMO: dict[str, Any] = {
    "camera": {"preset": "aa-str"},
    # the moon: the default real Moon (LOLA LDEM_4, LROC albedo, ROLO-calibrated Hapke)
    "trajectory": {"source": "halo", "duration_days": 0.5, "cadence_s": 1800.0},
    "pointing": {"moon_offset": "random", "moon_offset_max_px": 300.0},
    "render": {"spp": 8, "aovs": False},
    "detector": {"exposure_time_s": 1.5e-5},
    # the filter's bias states: tuned on other arcs (tuned_filter, in demo_scenario)
    "navigation": {"fix": {"attitude_sigma_arcsec": None}},
}

#: Exposures of the demo dataset [s]: the paper's well-exposed case and its 7.7 ms case.
DEMO_EXPOSURES_S: tuple[float, ...] = (1.5e-5, 7.7e-3)
#: Per-exposure overrides of the demo, as the paper tuned its processing to each scenario: the
#: saturated 7.7 ms frames are read out at half scale (the stray-light halo and the ghost exceed
#: the default 200 DN threshold there) and the EKF estimates Gauss-Markov biases for a range
#: scale (saturation pushes the limb outwards) and a 3-axis shift (unevenly along the arc, which
#: moves the fitted centre). Both exposures take the bias states tuned for them on calibration
#: arcs (:func:`tuned_filter`; on the real Moon even the well-exposed fixes carry a slowly
#: varying lit-terrain bias, docs/navigation.md).
DEMO_EXPOSURE_OVERRIDES: tuple[tuple[float, tuple[str, ...]], ...] = (
    (7.7e-3, ("detector.readout.segments.thresholds_dn=[2048]",
              *(f"navigation.filter.{k}={v}" for k, v in tuned_filter(7.7e-3).items()))),)


def demo_scenario() -> dict[str, Any]:
    """The complete scenario of the demo (:func:`starnav.batch.main_job`): :data:`DEMO` with
    the filter's bias states tuned for 0.015 ms (:func:`tuned_filter`)."""
    d = dict(DEMO)
    d["navigation"] = {**DEMO["navigation"], "filter": tuned_filter(1.5e-5)}
    return _resolved(d)


# ============================================================================ registry
@dataclass(frozen=True)
class SweepPreset:
    """A named sweep: scenario, grid and runs."""

    name: str
    description: str
    scenario: Callable[[], dict[str, Any]]
    grid: tuple[str, ...]
    runs: int


PRESETS: Registry[SweepPreset] = Registry("sweep preset", {p.name: p for p in (
    SweepPreset(
        "exposure-study", "the paper's four exposures (200, 7.7, 0.18, 0.015 ms)",
        exposure_study_scenario, EXPOSURE_STUDY_GRID, 5),
)})


def get_preset(name: str) -> SweepPreset:
    """The preset ``name``; an unknown name lists the known ones."""
    return PRESETS.get(name)


# ============================================================================ fly-by
#: The asteroid fly-by of ``starnav init --preset flyby``: the AA-STR itself (its optics and
#: detector, :data:`starnav.camera.CAMERA_PRESETS` ``aa-str``: 1024 x 1024 px, 20.6 deg) reading
#: the segments then at most 16 windows per frame, passing Itokawa from 16 km out to closest
#: approach at 5 km and out again (0.5 km/s, 60 s, 241 frames: the closed loop holds every
#: frame's radiance, 25 MB at 1024 x 1024, so 6 GB; the pass from 50 km, 801 frames, needs
#: 20 GB: ``trajectory.flyby.start_s: -100``, ``end_s: 100``). The cadence, 0.25 s, is the shortest
#: quarter second the readout law allows for both acquisitions of a frame
#: (:func:`starnav.simulate.trn.flyby_frame_budget`: 2 x 30 us of exposure, 200 ms for the
#: segments, at most 19.1 ms for 16 windows of 64 x 64 px); the exposure, 30 us, puts the lit
#: body's brightest pixels at about half of the ADC's range (well exposed, no saturation).
FLYBY: dict[str, Any] = {
    "camera": {"preset": "aa-str"},
    "render": {"spp": 4},
    "target": {"kind": "shape_model", "model": "itokawa"},
    "trajectory": {"source": "flyby", "cadence_s": 0.25,
                   "flyby": {"closest_approach_km": 5.0, "v_inf_km_s": 0.5,
                             "phase_at_ca_deg": 60.0, "start_s": -30.0, "end_s": 30.0}},
    "pointing": {"moon_offset": "fixed", "roll": "fixed"},
    "detector": {"exposure_time_s": 3e-5},
    "navigation": {"trn": {"front_end": {"n_windows": 16}, "shape_model": {"map": "coarse"}}},
    "seed": 7}


def flyby_header() -> str:
    """The comment block of the fly-by preset."""
    return ("# preset: asteroid fly-by terrain-relative navigation on the AA-STR\n"
            "# Itokawa (radar shape model, Hapke S-type) passed at 5 km and 0.5 km/s from 16 km\n"
            "# out and back (Sun phase 60 deg at CA), the AA-STR (1024 x 1024 px, 20.6 deg)\n"
            "# reading segments then up to 16 windows, 241 frames 0.25 s apart (the readout\n"
            "# law's frame budget: docs/navigation.md). The estimator navigates on a coarse\n"
            "# shape model (navigation.trn.shape_model). 6 GB of frames in memory; ~1 s a frame:\n"
            "#   starnav navigate flyby.yaml --out out/flyby --runs 20\n"
            "# a short one: --set trajectory.flyby.start_s=-2 --set trajectory.flyby.end_s=2\n")


def flyby_scenario() -> dict[str, Any]:
    """The complete fly-by preset scenario."""
    return _resolved(dict(FLYBY))
