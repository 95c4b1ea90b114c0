"""The four bench workflows behind ``starnav hil``: check, geometric, radiometric, stimulate.

Each takes a validated :class:`~starnav.calibration.schema.BenchConfig`, runs the library
steps and returns a :class:`HilReport` (JSON-safe summary, matplotlib figures, text files);
the CLI only writes them. The rendered reference frame is the first frame of the bench's
scenario (``scenario.geometry`` or ``scenario.trajectory``), rendered with Mitsuba.

Example
-------
>>> from starnav.calibration import BenchConfig
>>> from starnav.calibration.workflows import run_check
>>> rep = run_check(BenchConfig())
>>> rep.summary["fills_field"]
False
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from starnav.atomic import atomic_path
from starnav.calibration import plots
from starnav.calibration.bench import Bench, check_bench
from starnav.calibration.collimator import implied_fov_deg
from starnav.calibration.geometric import (
    GeometricCalibration,
    NominalMapping,
    ScreenMapping,
    calibrate_geometry,
    random_layout_holdout,
)
from starnav.calibration.intrinsics import calibrate_camera
from starnav.calibration.moon_stimulus import compare_moon_stimulus
from starnav.calibration.radiometric import compare_stimulus, count_flux_mapping, moon_flux
from starnav.calibration.radiometric_lab import calibrate_radiometry, radiometric_lab
from starnav.calibration.radiometric_truth import ReferenceInstrument, TruthScreen
from starnav.calibration.scaling import (
    albedo_exposure_experiment,
    bench_min_exposure,
    end_to_end,
    plan_scaling,
)
from starnav.calibration.schema import BenchConfig, bench_to_dict
from starnav.calibration.star_field import run_star_field_holdout
from starnav.config_base import read_json_file
from starnav.errors import ConfigError, DataFileError
from starnav.radiance import RadianceImage, read_exr
from starnav.simulate import frame_geometries, renderer_from_scenario

log = logging.getLogger(__name__)

#: The paper's stated bound on the collimator focal length [mm] (seed paper, below eq. 2).
PAPER_F_COLL_BOUND_MM = 180.07


@dataclass
class HilReport:
    """What a workflow produced.

    Attributes
    ----------
    summary : dict
        JSON-safe results.
    figures : dict of str -> matplotlib Figure
        Saved as ``<name>.png``.
    texts : dict of str -> str
        Extra files (e.g. ``geometric_calibration.json``).
    """

    summary: dict[str, Any]
    figures: dict[str, Any] = field(default_factory=dict)
    texts: dict[str, str] = field(default_factory=dict)


def render_reference(cfg: BenchConfig, albedo_scale: float = 1.0) -> RadianceImage:
    """The first frame of the bench's scenario, rendered with ``moon.albedo_scale`` multiplied
    by ``albedo_scale`` (renders are linear in albedo)."""
    sc = cfg.scenario
    if albedo_scale != 1.0:
        sc = sc.model_copy(update={"moon": sc.moon.model_copy(
            update={"albedo_scale": sc.moon.albedo_scale * albedo_scale})})
    frames = frame_geometries(sc)
    if not frames:
        raise ConfigError("scenario", "no frame", "a scenario with at least one frame")
    return renderer_from_scenario(sc).render(frames[0], seed=sc.seed)


# =========================================================================== check
def run_check(cfg: BenchConfig) -> HilReport:
    """Optical-stimulator condition (eq. 2, stated and derived FoV) and detector coverage."""
    bench = Bench(cfg)
    chk = check_bench(bench)
    cam = bench.camera
    summary = {
        "camera": {"fov_x_deg": math.degrees(cam.fov_x), "fov_y_deg": math.degrees(cam.fov_y),
                   "fov_diagonal_deg": math.degrees(cam.fov_diagonal),
                   "ifov_arcsec": math.degrees(cam.ifov) * 3600},
        "paper": {"stated_bound_f_coll_mm": PAPER_F_COLL_BOUND_MM,
                  "fov_implied_by_that_bound_deg": implied_fov_deg(cfg.screen.height_mm,
                                                                   PAPER_F_COLL_BOUND_MM)},
        **chk.to_dict(),
    }
    return HilReport(summary, {"coverage": plots.coverage(bench, chk)})


# =========================================================================== geometric
def run_geometric(cfg: BenchConfig, *, moon: bool = True,
                  image: RadianceImage | None = None) -> HilReport:
    """Dot-pattern calibration, residuals (Fig. 12), the displayed-Moon check (Fig. 13), the
    camera's intrinsics and the radiometric calibration against the reference instrument with
    its hold-out validation (:mod:`~starnav.calibration.radiometric_lab`), the camera's
    hold-out on the star-field stimulus (:mod:`~starnav.calibration.star_field`); both calibrations
    go to ``camera_calibration.json``.

    Parameters
    ----------
    moon : bool
        Also display the scenario's rendered Moon through the calibration (and uncalibrated)
        and measure where it lands.
    image : RadianceImage, optional
        The Moon frame to use instead of rendering the scenario's first frame.
    """
    bench = Bench(cfg)
    res = calibrate_geometry(bench)
    intr = calibrate_camera(bench, res.calibration_dots)
    lab = radiometric_lab(bench, bench.chain_detector())
    summary: dict[str, Any] = {"geometric": res.summary(), "camera": intr.summary(),
                               "random_layout_holdout": random_layout_holdout(
                                   bench, res.calibration, exposure_time=res.exposure_time,
                                   dark_dn=res.calibration_dots.dark_dn),
                               "star_field_holdout": run_star_field_holdout(
                                   bench, intr, exposure_time=res.exposure_time,
                                   dark_dn=res.calibration_dots.dark_dn),
                               "radiometric_lab": lab.summary()}
    figs = {"residuals_pdf_cdf": plots.residual_pdf_cdf(res),
            "dot_displacements": plots.dot_displacements(res)}
    if moon:
        img = image if image is not None else render_reference(cfg)
        t = cfg.scaling.render_exposure_ms * 1e-3
        cal = compare_stimulus(bench, img, t, res.calibration, frame_base=500)
        unc = compare_stimulus(bench, img, t, NominalMapping(bench.geometry.nominal()),
                               frame_base=510)
        summary["moon_placement"] = {
            "calibrated_offset_px": cal.metrics()["centroid_offset_px"],
            "uncalibrated_offset_px": unc.metrics()["centroid_offset_px"],
            "goal_px": 0.5, "calibrated": cal.metrics(), "uncalibrated": unc.metrics()}
        figs["moon_placement"] = plots.moon_placement(cal, unc)
    summary["bench"] = bench_to_dict(cfg)
    return HilReport(summary, figs, {"geometric_calibration.json": res.calibration.to_json(),
                                     "camera_calibration.json": _json(replace(
                                         intr.calibration,
                                         radiometric=lab.calibration.to_dict()).to_dict())})


def load_calibration(path: str | Path, bench: Bench) -> GeometricCalibration:
    """Read a ``geometric_calibration.json`` written by ``hil geometric``."""
    return GeometricCalibration.from_dict(read_json_file(path, "geometric calibration file"),
                                          bench.camera)


def _calibration(bench: Bench, calibration: GeometricCalibration | str | Path | None
                 ) -> ScreenMapping:
    if calibration is None:
        log.info("no geometric calibration given: running the emulated dot calibration")
        return calibrate_geometry(bench, validate=False).calibration
    if isinstance(calibration, str | Path):
        return load_calibration(calibration, bench)
    return calibration


# =========================================================================== radiometric
def run_radiometric(cfg: BenchConfig,
                    calibration: GeometricCalibration | str | Path | None = None, *,
                    image: RadianceImage | None = None,
                    image_scaled: RadianceImage | None = None) -> HilReport:
    """Screen flux per count, Moon flux, the count <-> flux mapping (Fig. 14), a calibrated
    stimulus validated against the in-orbit exposure (Figs. 15-16), the albedo-exposure
    equivalence test (Fig. 18) and the end-to-end case (Fig. 19).

    With ``radiometric_truth.enabled`` (the default) the equivalence test and the end-to-end
    case run on the truth bench (counts from the radiometric calibration against the reference
    instrument, shown on the truth screen); the validation runs on the nominal bench model.

    Parameters
    ----------
    calibration : GeometricCalibration or path, optional
        Default: run the emulated geometric calibration first.
    image, image_scaled : RadianceImage, optional
        The rendered frame at the true albedo and at albedo / k (default: rendered here).
    """
    bench = Bench(cfg)
    rad = bench.radiometry
    mapping = _calibration(bench, calibration)
    img = image if image is not None else render_reference(cfg)
    mf = moon_flux(img, bench.camera)
    cfm = count_flux_mapping(rad, bench.camera, mf.electrons_per_joule)
    t_r = cfg.scaling.render_exposure_ms * 1e-3
    t_b = cfg.scaling.bench_exposure_ms * 1e-3 if cfg.scaling.bench_exposure_ms else None
    plan = plan_scaling(mf.peak_le, t_r, rad, bench_min_exposure_s=bench_min_exposure(bench),
                        bench_exposure_s=t_b, headroom=cfg.radiometric.headroom_fraction)
    valid = compare_stimulus(bench, img, t_r, mapping, frame_base=600)
    lab: dict[str, Any] = {}
    if cfg.radiometric_truth.enabled:
        # the equivalence on the bench as it is: counts from the lab's calibration against
        # the reference, shown on the truth screen
        truth = TruthScreen(bench)
        inst = ReferenceInstrument(bench, truth)
        lab = {"truth": truth, "instrument": inst,
               "calibration": calibrate_radiometry(bench, truth, inst)}
    ks = albedo_exposure_experiment(bench, img, t_r, mapping, **lab)
    scaled = image_scaled if image_scaled is not None else render_reference(cfg, plan.albedo_factor)
    e2e = end_to_end(bench, img, mapping, le_scaled=scaled, render_exposure_s=t_r,
                     bench_exposure_s=plan.bench_exposure_s, **lab)
    summary = {
        "screen": {"max_count": rad.max_count, "full_white_le_e_s_m2_sr": rad.le_max,
                   "full_white_l_w_m2_sr": float(rad.l_lut[-1]),
                   "full_white_electron_rate_px_e_s": rad.le_max * bench.camera.etendue,
                   "electrons_per_joule_e_j": rad.electrons_per_joule,
                   "throughput": rad.throughput,
                   "emittance_source": cfg.screen.emittance.source if cfg.screen.emittance
                   else None},
        "moon": mf.to_dict(),
        "screen_too_dim_factor": mf.peak_le / rad.le_max,
        "mapping_excerpt": {str(n): {"moon_equivalent_l_w_m2_sr": float(cfm.moon_equivalent_l[n]),
                                     "moon_equivalent_flux_px_w_m2":
                                     float(cfm.moon_equivalent_flux_px[n])}
                            for n in sorted({1, 13, 52, 128, rad.max_count})
                            if n <= rad.max_count},
        "plan": plan.to_dict(),
        "validation": valid.metrics(),
        "albedo_exposure_ks": ks.to_dict(),
        "end_to_end": e2e.to_dict(),
    }
    figs = {"count_flux_mapping": plots.count_flux(cfm, mf, plan),
            "radiometric_validation": plots.stimulus_comparison(
                valid, "calibrated stimulus vs in-orbit exposure (screen-limited k)"),
            "albedo_exposure_histograms": plots.ks_histograms(ks),
            "end_to_end": plots.end_to_end_figure(e2e)}
    return HilReport(summary, figs, {"count_flux_mapping.json": _json(cfm.to_dict())})


def _json(d: dict[str, Any]) -> str:
    return json.dumps(d, indent=1)


# =========================================================================== stimulate
FrameSink = Callable[[str, NDArray[np.uint16], NDArray[np.float64], NDArray[np.float64]], None]


def png_frame_sink(out: str | Path, screen_bit_depth: int) -> FrameSink:
    """A :data:`FrameSink` writing, per frame, the screen counts
    (``screen/NAME.png``, 8 or 16 bit as the screen), the predicted bench acquisition and the
    in-orbit exposure (``predicted/NAME_dn.png``, ``orbit/NAME_dn.png``, 16-bit DN), each
    atomically."""
    import imageio.v3 as iio

    out = Path(out)
    dtype = np.uint8 if screen_bit_depth <= 8 else np.uint16

    def png(path: Path, arr: NDArray[Any]) -> None:
        with atomic_path(path, suffix=".png") as tmp:
            iio.imwrite(tmp, arr, extension=".png")

    def dn16(x: NDArray[np.float64]) -> NDArray[np.uint16]:
        return np.clip(np.rint(x), 0, 65535).astype(np.uint16)

    def sink(name: str, counts: NDArray[np.uint16], dn: NDArray[np.float64],
             orbit: NDArray[np.float64]) -> None:
        png(out / "screen" / f"{name}.png", counts.astype(dtype))
        png(out / "predicted" / f"{name}_dn.png", dn16(dn))
        png(out / "orbit" / f"{name}_dn.png", dn16(orbit))

    return sink


def run_stimulate(cfg: BenchConfig, dataset: str | Path, sink: FrameSink,
                  calibration: GeometricCalibration | str | Path | None = None,
                  progress: Callable[[int, int], None] | None = None) -> HilReport:
    """Screen stimuli for every rendered frame of a directory, and the predicted acquisitions.

    ``dataset`` is a directory of RadianceImage
    EXRs as written by ``starnav render`` (``*.exr``, sorted by name). One factor k serves the
    whole sequence (the brightest frame decides), so the bench exposure is constant.

    With ``radiometric_truth.enabled`` (the default) the bench is the truth bench: the screen
    is calibrated against the reference instrument first, the counts come from that
    calibration and the predicted acquisition is the truth screen's
    (:func:`~starnav.calibration.moon_stimulus.compare_moon_stimulus`: each frame's metrics
    carry the budget and the verdict); without it, the nominal bench model
    (:func:`~starnav.calibration.radiometric.compare_stimulus`).

    Parameters
    ----------
    sink : callable
        ``sink(frame_name, screen_counts, predicted_dn, in_orbit_dn)`` for each frame (the CLI
        writes them as PNG).
    calibration : GeometricCalibration or path, optional
        Default: run the emulated geometric calibration first.
    progress : callable, optional
        ``progress(done, total)``.

    Raises
    ------
    DataFileError
        No EXR in ``dataset``.
    ConfigError
        A frame whose size differs from the bench camera's.
    """
    d = Path(dataset)
    files = sorted(d.glob("*.exr")) if d.is_dir() else []
    if not files:
        raise DataFileError(f"{str(d)!r} holds no RadianceImage EXR (*.exr written by "
                            "`starnav render`)")
    bench = Bench(cfg)
    cam = bench.camera
    peaks = []
    for f in files:
        img = read_exr(f)
        if img.shape != (cam.height, cam.width):
            raise ConfigError(f"{f.name} size", f"{img.shape[0]} x {img.shape[1]}",
                              f"the bench camera's {cam.height} x {cam.width} (rows x cols)")
        peaks.append(float(img.Le.max()))
    if max(peaks) <= 0:
        raise ConfigError("dataset", str(d), "at least one frame with the Moon in the field")
    mapping = _calibration(bench, calibration)
    t_r = cfg.scaling.render_exposure_ms * 1e-3
    t_b = cfg.scaling.bench_exposure_ms * 1e-3 if cfg.scaling.bench_exposure_ms else None
    plan = plan_scaling(max(peaks), t_r, bench.radiometry,
                        bench_min_exposure_s=bench_min_exposure(bench), bench_exposure_s=t_b,
                        headroom=cfg.radiometric.headroom_fraction)
    frames = []
    first = None
    lab = None
    if cfg.radiometric_truth.enabled:
        # the bench as it is: counts from the lab's calibration against the reference,
        # shown on the truth screen
        truth = TruthScreen(bench)
        inst = ReferenceInstrument(bench, truth)
        lab = (truth, inst, calibrate_radiometry(bench, truth, inst))
    det = bench.chain_detector()
    for i, f in enumerate(files):
        img = read_exr(f)
        if peaks[i] <= 0:
            log.warning("%s: no Moon in the field; skipped", f.name)
            continue
        if lab is None:
            comp = compare_stimulus(bench, img, t_r, mapping, det,
                                    bench_exposure_s=plan.bench_exposure_s,
                                    frame_base=1000 + 4 * i)
            metrics = comp.metrics() | {"truth_bench": False}
        else:
            mc = compare_moon_stimulus(bench, img, t_r, mapping, lab[2], lab[0], lab[1], det,
                                       bench_exposure_s=plan.bench_exposure_s,
                                       frame_base=1000 + 4 * i)
            comp, metrics = mc.comparison, mc.metrics()
        sink(f.stem, comp.counts, comp.bench.dn, comp.orbit_dn)
        frames.append({"frame": f.name} | metrics)
        if first is None:
            first = comp
        if progress is not None:
            progress(i + 1, len(files))
    summary = {"dataset": str(d), "dataset_format": "directory of RadianceImage EXRs "
               "as `starnav render` writes them",
               "plan": plan.to_dict(), "frames": frames,
               "stimulus_path": "truth bench, counts from the radiometric calibration against "
               "the reference instrument" if lab is not None else "nominal bench model"}
    if lab is not None:
        summary["radiometric_calibration"] = {
            "counts": lab[2].counts.tolist(), "le_e_s_m2_sr": lab[2].le.tolist(),
            "provenance": lab[2].provenance, "truth": lab[0].summary()}
    figs = {}
    if first is not None:
        figs["first_frame"] = plots.stimulus_comparison(first, f"{frames[0]['frame']}: bench vs "
                                                        "in orbit")
    return HilReport(summary, figs)


__all__ = ["HilReport", "load_calibration", "render_reference", "run_check", "run_geometric",
           "run_radiometric", "run_stimulate"]
