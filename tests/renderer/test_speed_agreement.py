"""Renders before and after the speed work agree within Monte Carlo noise (issue 18).

``data/render_reference.npz`` holds, for each standard radiometric case below, the per-pixel
mean and standard deviation of ``L`` and ``Le`` over ``K`` independent sampler seeds, rendered
by the renderer as it was *before* the speed work (commit b35a942, pinned with
``python -m tests.renderer.test_speed_agreement``), plus the pixel-centre AOV channels of a
sphere and a mesh case (deterministic: one non-jittered sample per pixel). Re-pinning it from
a later renderer would defeat its purpose (the comparison with the renderer before issue 18).

The test renders the same cases with the current renderer and other seeds and, per lit pixel,
forms Welch's statistic ``t = (m_new - m_ref) / sqrt((s_new^2 + s_ref^2) / K)``. With an
unbiased renderer and both estimates from ``K`` = 8 seeds, ``t`` follows Student's t with
``K - 1`` = 7 degrees of freedom or more (Welch-Satterthwaite; equal variances give 14); the
count of pixels with ``|t|`` above the 7-dof critical value at alpha = 1e-3 is then at most
Binomial(n, 1e-3), and the bound used is that Binomial's Poisson tail at 1e-6: the per-case
false-alarm rate. A second check sums each image over the disc: the difference of the sums
over its standard error is a z-score; ``|z| > 5`` has a false-alarm rate of 6e-7 and detects a
bias of ~0.2 % of the disc radiance. Background pixels (zero variance in both) must be exactly
zero in both; the AOV channels must equal the pinned ones to float32 rounding.

The current renders draw their wavelengths by the lit surface's electron spectrum
(``render.spectral_sampling: electrons``, the default since 2026-11-27), the pinned ones by the
sensor response: the test also checks that the two samplings integrate the same radiance (the
``hapke_map_colour`` case carries the ROLO colour, the others a grey surface under the solar
spectrum).

Each case runs twice: with ``SPP`` samples in every pixel and
with the adaptive samples per pixel (``render.adaptive``, ``ADAPTIVE_INTERIOR_SPP`` = 1 sample
in the flat interior, ``SPP`` at the limb and the terminator): the same test against the same
reference, each side with its own per-pixel noise. The adaptive render's interior pixels are
means of one sample per seed, whose distribution over seeds is further from normal than a
4-sample mean's; Welch's t stays within the bound (the count of ``|t|`` beyond the 7-dof
critical value is the statistic, and with ``K = 8`` it is robust to that skew).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from starnav.bodies.mesh import icosphere_mesh
from starnav.bodies.model import AlbedoMap, TargetModel
from starnav.camera import Camera
from starnav.geometry import static_geometry
from starnav.lunar_calibration import lunar_calibration
from starnav.renderer.render import MoonRenderer, RenderSettings
from starnav.spectra import sensor_response, solar_spectrum

from .conftest import require_jit

REFERENCE = Path(__file__).parent / "data" / "render_reference.npz"
K = 8
SPP = 4
#: Samples of an interior pixel in the adaptive renders (the fewest possible: the strongest
#: test of the sample map and of the per-count passes).
ADAPTIVE_INTERIOR_SPP = 1
#: Seeds of the pinned (before) renders and of the fresh (after) ones: independent streams.
SEEDS_BEFORE = tuple(range(500, 500 + K))
SEEDS_AFTER = tuple(range(900, 900 + K))
ALPHA = 1e-3
FALSE_ALARM = 1e-6
Z_SUM_MAX = 5.0
#: AOVs are float32 image channels of the pixel-centre ray, which the fused loop forms from
#: full-frame film coordinates (Mitsuba's from crop coordinates: the same ray to float32
#: rounding). Range: 4 float32 ulps at 2.6e8 m (16 m each); angles and lat/lon go through
#: arccos/arctan2 (1 float32 ulp of a cosine near 1 is 3.5e-4 rad; longitude near a pole).
AOV_ATOL = {"range": 64.0, "incidence": 5e-4, "emission": 5e-4, "phase": 5e-4, "lat": 5e-4,
            "lon": 5e-4}
AOV_DEFAULT_ATOL = 2e-5
#: Cases whose AOVs are pinned (they do not depend on the photometry: a sphere and a mesh).
AOV_CASES = ("hapke", "hapke_mesh")


def _camera() -> Camera:
    return Camera.preset("aa-str", width=40, height=40)


def _albedo_map() -> AlbedoMap:
    lat = np.linspace(math.pi / 2, -math.pi / 2, 32)[:, None]
    lon = np.linspace(-math.pi, math.pi, 64, endpoint=False)[None, :]
    return AlbedoMap((0.11 + 0.05 * np.cos(3 * lon) * np.cos(lat) ** 2
                      + 0.02 * np.sin(2 * lat)).astype(np.float32), "synthetic")


def _cases() -> dict[str, TargetModel]:
    cal = lunar_calibration()
    return {
        "lambert": TargetModel(shape="sphere", model="lambert", albedo=0.12),
        "lommel_seeliger": TargetModel(shape="sphere", model="lommel_seeliger", albedo=0.25),
        "lunar_lambert": TargetModel(shape="sphere", model="lunar_lambert", albedo=0.25),
        "hapke": TargetModel(shape="sphere", model="hapke", albedo=0.25),
        "hapke_smooth": TargetModel(shape="sphere", model="hapke", albedo=0.25,
                                  params={"theta_bar_deg": 0.0, "bs0": 0.0}),
        # the real Moon's ingredients: calibrated Hapke, an albedo map, the ROLO colour
        "hapke_map_colour": TargetModel(shape="sphere", model="hapke", albedo=_albedo_map(),
                                      params=dict(cal.hapke), spectral_shape=cal.spectral_shape(),
                                      calibrated=True),
        "hapke_mesh": TargetModel(shape="mesh", model="hapke", albedo=0.25,
                                mesh=icosphere_mesh(1.7374e6, 5)),
    }


#: Phase angle [deg] and Moon offset [px] of each case's frame: 2.6e8 m puts a ~36 px disc on
#: the 40 px frame, limb and terminator both present.
PHASE_DEG = {"lambert": 30.0, "lommel_seeliger": 50.0, "lunar_lambert": 70.0, "hapke": 40.0,
             "hapke_smooth": 20.0, "hapke_map_colour": 60.0, "hapke_mesh": 45.0}
RANGE_M = 2.6e8


def render_stats(case: str, seeds: tuple[int, ...], adaptive: bool = False
                 ) -> dict[str, np.ndarray]:
    """Per-pixel mean and standard deviation (ddof 1) of L and Le over ``seeds``, and (for
    :data:`AOV_CASES`) the AOVs of the first render; ``adaptive``: with the adaptive samples
    per pixel (and the sample counts of the first render as ``counts``)."""
    cam = _camera()
    moon = _cases()[case]
    r = MoonRenderer(cam, sensor_response(), solar_spectrum(), moon,
                     RenderSettings(spp=SPP, variants=("llvm_ad_spectral", "scalar_spectral"),
                                    adaptive=adaptive, interior_spp=ADAPTIVE_INTERIOR_SPP))
    g = static_geometry(cam, RANGE_M, math.radians(PHASE_DEG[case]), (1.5, -1.0))
    imgs = []
    counts = None
    for s in seeds:
        imgs.append(r.render(g, seed=s))
        if counts is None:
            counts = r.last_sample_counts
    out = {}
    if counts is not None:
        out["counts"] = counts
    for ch in ("L", "Le"):
        stack = np.stack([getattr(im, ch).astype(np.float64) for im in imgs])
        out[f"{ch}_mean"] = stack.mean(0)
        out[f"{ch}_std"] = stack.std(0, ddof=1)
    if case in AOV_CASES:
        for name, v in imgs[0].aovs.items():
            out[f"aov_{name}"] = v
    return out


def pin() -> None:
    """Write :data:`REFERENCE` from the renderer as it is now (run before changing it)."""
    arrays = {}
    for case in _cases():
        for k, v in render_stats(case, SEEDS_BEFORE).items():
            arrays[f"{case}/{k}"] = v.astype(np.float32)
    REFERENCE.parent.mkdir(exist_ok=True)
    np.savez_compressed(REFERENCE, **arrays)


@pytest.fixture(scope="module")
def reference():
    with np.load(REFERENCE) as z:
        return {k: z[k].astype(np.float64) for k in z.files}


@pytest.mark.parametrize("adaptive", [False, True], ids=["spp", "adaptive"])
@pytest.mark.parametrize("case", list(PHASE_DEG))
def test_render_agrees_with_the_pinned_render_within_mc_noise(reference, case, adaptive):
    new = render_stats(case, SEEDS_AFTER, adaptive)
    if adaptive:
        counts = new.pop("counts", None)
        require_jit(counts is not None, "the adaptive render")
        # both sample counts are in use: the test compares both kinds of pixel
        lit = reference[f"{case}/L_mean"] > 0
        assert np.count_nonzero(lit & (counts == ADAPTIVE_INTERIOR_SPP)) > 100, case
        assert np.count_nonzero(lit & (counts == SPP)) > 100, case
    for ch in ("L", "Le"):
        m0, s0 = reference[f"{case}/{ch}_mean"], reference[f"{case}/{ch}_std"]
        m1, s1 = new[f"{ch}_mean"], new[f"{ch}_std"]
        # float32 storage of the reference: its relative rounding, 6e-8, is far below the noise
        var = (s0 * s0 + s1 * s1) / K
        lit = var > 0
        dark = ~lit & (m0 == 0)
        assert np.all(m1[dark] == 0), f"{case} {ch}: light where the pinned render is black"
        n = int(lit.sum())
        assert n > 600, (case, n)  # the disc is lit and noisy
        t = (m1[lit] - m0[lit]) / np.sqrt(var[lit])
        crit = stats.t.ppf(1 - ALPHA / 2, K - 1)
        n_out = int(np.sum(np.abs(t) > crit))
        bound = stats.poisson.ppf(1 - FALSE_ALARM, n * ALPHA)
        assert n_out <= bound, f"{case} {ch}: {n_out} pixels beyond |t| > {crit:.2f} (<= {bound})"
        z_sum = (m1.sum() - m0.sum()) / math.sqrt(var.sum())
        assert abs(z_sum) < Z_SUM_MAX, f"{case} {ch}: disc sums differ by {z_sum:.1f} sigma"
    for key, v in new.items():
        if key.startswith("aov_"):
            name = key[4:]
            ref = reference[f"{case}/{key}"]
            np.testing.assert_allclose(v, ref, rtol=1e-6,
                                       atol=AOV_ATOL.get(name, AOV_DEFAULT_ATOL),
                                       err_msg=f"{case} AOV {name}")


def test_the_check_detects_a_half_percent_bias(reference):
    """The same statistics reject a render 0.5 % too bright: the test can fail."""
    case = "hapke"
    new = render_stats(case, SEEDS_AFTER)
    m0, s0 = reference[f"{case}/L_mean"], reference[f"{case}/L_std"]
    m1, s1 = new["L_mean"] * 1.005, new["L_std"] * 1.005
    var = (s0 * s0 + s1 * s1) / K
    z_sum = (m1.sum() - m0.sum()) / math.sqrt(var.sum())
    assert z_sum > Z_SUM_MAX


def _pair(shape: str, spp: int):
    cam = Camera.preset("aa-str", width=96, height=96)
    mesh = icosphere_mesh(1.7374e6, 4) if shape == "mesh" else None

    def one(fused: bool) -> MoonRenderer:
        return MoonRenderer(cam, sensor_response(), solar_spectrum(),
                            TargetModel(shape=shape, model="hapke", albedo=0.25, mesh=mesh),
                            RenderSettings(spp=spp, fused_loop=fused, adaptive=False,
                                           variants=("llvm_ad_spectral", "scalar_spectral")))
    return cam, one(True), one(False)


@pytest.mark.parametrize("shape,spp", [("sphere", 4), ("mesh", 6)])
def test_fused_loop_traces_mitsubas_samples(shape, spp):
    """The fused loop and ``mi.render`` draw the same samples for the same seed: the images
    agree per pixel to float32 rounding (the rays come from full-frame instead of crop film
    coordinates, and the sums of non-power-of-two spp run in another order), far below the
    Monte Carlo noise (~1e-2 per pixel at these spp), on the sphere and on a mesh."""
    cam, fused, ref = _pair(shape, spp)
    g = static_geometry(cam, 1.5e8, math.radians(50.0), (4.0, -3.0))
    a, b = fused.render(g, seed=11), ref.render(g, seed=11)
    require_jit(not a.meta["render"]["variant"].startswith("scalar"), "the fused loop")
    for ch in ("L", "Le"):
        x, y = getattr(a, ch), getattr(b, ch)
        assert np.array_equal(x > 0, y > 0)
        # a sample moved across the limb by a rounding would change its pixel by ~1/spp
        rel = np.abs(x - y) / y.max()
        assert np.max(rel) < 2e-5, (ch, float(np.max(rel)))
        assert np.mean(rel[y > 0]) < 5e-7
    np.testing.assert_array_equal(a.aovs["mask"], b.aovs["mask"])
    # the seed matters (a fused loop ignoring it would agree with nothing)
    c = fused.render(g, seed=12)
    assert np.max(np.abs(c.L - b.L)) / b.L.max() > 1e-3


@pytest.mark.parametrize("adaptive", [False, True], ids=["spp", "adaptive"])
def test_a_new_crop_window_reuses_the_compiled_kernels(adaptive):
    """Mitsuba bakes the film crop into its kernels; the fused loop passes it as data, so a
    frame whose Moon box moves and changes size runs the kernels compiled for the previous
    frame (in-memory cache hits; no compilation, no disk-cache load). The adaptive render's
    kernels (centre pass, one radiance pass per sample count) too, with other pixel lists."""
    import drjit as dr

    cam, fused, _ = _pair("sphere", 4)
    fused.settings = dataclasses.replace(fused.settings, adaptive=adaptive, interior_spp=1)
    g1 = static_geometry(cam, 1.5e8, math.radians(50.0), (4.0, -3.0))
    g2 = static_geometry(cam, 1.4e8, math.radians(55.0), (-7.0, 5.0), roll=0.2)
    a = fused.render(g1, seed=1)
    require_jit(not a.meta["render"]["variant"].startswith("scalar"), "kernel caching")
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()  # clears it
        b = fused.render(g2, seed=2)
        jit = [h for h in dr.kernel_history() if h["type"] == dr.KernelType.JIT]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert a.meta["render"]["crop_box_uvwh"] != b.meta["render"]["crop_box_uvwh"]
    assert a.meta["render"]["crop_box_uvwh"][2:] != b.meta["render"]["crop_box_uvwh"][2:]
    assert jit, "no kernel ran"
    fresh = [(h["size"], h["operation_count"]) for h in jit
             if not h["cache_hit"] or h["cache_disk"]]
    assert not fresh, f"kernels compiled or loaded for the new crop window: {fresh}"
    if adaptive:
        assert a.meta["render"]["adaptive"]["pixels_interior"] > 0
        assert len([h for h in jit if h["size"] > 1000]) >= 3  # centre, full, interior


if __name__ == "__main__":
    pin()
