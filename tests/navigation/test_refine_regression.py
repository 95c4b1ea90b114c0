"""The batched refinement (issue 18) reproduces the per-window fit it replaced.

Seeded regression test (exact frames, pinned outputs; the frames are synthetic, NumPy in double
precision with no Dr.Jit render, so the pins hold on any CPU): ``data/refine_pins.json`` holds
the refined points, their sigmas and the fix of a few frames as the per-window Levenberg-
Marquardt implementation (commit 7e3f772) gave them. The batched fit must agree to 1e-3 px in
position, 1 % in sigma and 1e-6 relative in the fix position: both minimise the same weighted
cost, and the old fit stopped within 1e-4 px of its minimum, so anything beyond that is a
different minimum, not rounding. Cases: the benchmark's 20 000 km frame (600 limb points, 16
windows, 0.8 px Gaussian PSF) refined with the Gaussian model of fitted width, with a known
width and noise, and with the detector-psf model, noise model and packaged calibration (the
pipeline's configuration); a disc through the detector's own optics, well exposed and saturated
(detector-psf, the saturated windows fitted without the ramp).

Saturated windows (2026-11-26): the detector-psf model's step and ramp are now the exact
integrals of the linearly interpolated line spread function (refine module, step 3b), so
the cost is smooth in the edge's position. The pinned fit interpolated them linearly too,
which with a step 5x the full scale made a saturated window's cost rough at the 1e-3 px level
(a kink wherever a pixel crosses a table sample, every ~2e-4 px; its minimum 2.4e-3 px from
the Gauss-Newton stationary point on window 8), and it stopped wherever its steps were first
rejected: window 3's pinned point is 2.2e-3 px from the minimum of the smooth cost. A
saturated point is therefore held to 0.1 of its fit sigma (0.010-0.043 px on this disc;
measured: at most 0.06 of it), the others to 1e-3 px.

Re-pin (only after an explained, legitimate change)::

    PYTHONPATH=src python tests/navigation/test_refine_regression.py
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from starnav.camera import Camera
from starnav.constants import AU
from starnav.detector.schema import AberrationPsfConfig
from starnav.navigation.pipeline import ChainOptions, process_frame
from starnav.navigation.ransac import ransac_limb
from starnav.navigation.refine import (
    EdgeSpread,
    PixelNoise,
    RefineConfig,
    RefineModels,
    cut_windows,
    packaged_model_error,
    plan_windows,
    refine_limb,
)
from starnav.navigation.synthetic import pointing_geometry, synthetic_frame

PINS = Path(__file__).with_name("data") / "refine_pins.json"
#: Agreement of the refined points [px], their sigmas [relative] and the fix [relative].
POINT_TOL_PX = 1e-3
#: Agreement of the points of saturated windows [fraction of their fit sigma] (docstring).
SATURATED_POINT_TOL = 0.1
SIGMA_TOL = 0.01
FIX_TOL = 1e-6

NOISE = PixelNoise(gain_e_per_dn=24.4, read_noise_e=100.0, prnu_fraction=0.02, offset_dn=0.0)
DISC_NOISE = PixelNoise(gain_e_per_dn=24.4, read_noise_e=100.0, prnu_fraction=0.02,
                        offset_dn=100.0)


def _psf_options(noise: PixelNoise, **kw) -> tuple:
    """The refinement's section (SI view) and resolved models of the detector-psf cases."""
    return (RefineConfig(edge_model="detector-psf", **kw).to_si(),
            RefineModels(spread=EdgeSpread(AberrationPsfConfig()), noise=noise,
                         model_error_table=packaged_model_error()))


def _bench_frame():
    """The 20 000 km frame of benchmarks/navigation.py (600 limb points, 16 windows)."""
    cam = Camera.preset("aa-str")
    t0, rng_km = 8.0e8, 20_000.0
    rel = np.array([1.0, 0.3, -0.2])
    rel *= rng_km * 1e3 / np.linalg.norm(rel)
    sun = AU * np.array([math.cos(1.0), math.sin(1.0), 0.05])
    g = pointing_geometry(cam, rel, sun, camera_velocity=np.array([0.0, 1000.0, 0.0]),
                          epoch_tdb=t0, moon_offset_px=(60.0, -40.0))
    frame = synthetic_frame(cam, g, supersample=4, psf_sigma_px=0.8, read_noise_dn=2.0,
                            rng=np.random.default_rng(0))
    return cam, frame


def _detector_disc(amplitude_dn: float, seed: int):
    """A uniform disc through the AA-STR's own optics with detector noise (as in
    test_refine._detector_disc), and 16 windows about it."""
    from starnav.detector.optics import apply_psf_grid, psf_grid

    cam = Camera.preset("aa-str")
    centre, radius = np.array([712.4, 331.7]), 62.3
    v, u = np.mgrid[0:1024, 0:1024].astype(float)
    r = np.hypot(u - centre[0], v - centre[1])
    img = (r < radius).astype(float)
    edge = np.abs(r - radius) < 1.0
    off = (np.arange(16) + 0.5) / 16 - 0.5
    du, dv = (a.ravel() for a in np.meshgrid(off, off))
    rr = np.hypot(u[edge][:, None] + du - centre[0], v[edge][:, None] + dv - centre[1])
    img[edge] = (rr < radius).mean(axis=1)
    clean, _ = apply_psf_grid((img * amplitude_dn).astype(np.float32),
                              psf_grid(cam, AberrationPsfConfig()))
    clean = clean + 100.0
    rng = np.random.default_rng(seed)
    dn = clean + rng.standard_normal(clean.shape) * np.sqrt(DISC_NOISE.variance_dn2(clean)
                                                            - 1 / 12)
    dn = np.clip(np.round(dn), 0, 4095)
    ang = np.linspace(0, 2 * math.pi, 16, endpoint=False) + math.radians(11.25)
    pts = centre + (radius + 0.3) * np.column_stack([np.cos(ang), np.sin(ang)])
    wins = cut_windows(dn, plan_windows(pts, centre, shape=dn.shape))
    return cam, wins, centre + 0.3, radius + 0.4


def _cases():
    """name -> (windows, centre, radius, (options, models), camera) of every pinned
    refinement."""
    cam, frame = _bench_frame()
    rr = ransac_limb(frame_limb(frame, cam).uv, cam, rng=np.random.default_rng(1))
    c, R = rr.params[:2], float(rr.params[2])
    out = {
        "bench-gauss-fitted": (frame.windows, c, R, (None, None), cam),
        "bench-gauss-known-noise": (frame.windows, c, R,
                                    (RefineConfig(psf_sigma_px=0.8).to_si(),
                                     RefineModels(noise=NOISE)), cam),
        "bench-detector-psf": (frame.windows, c, R, _psf_options(NOISE), cam),
    }
    for name, amp in (("disc-well-exposed", 1500.0), ("disc-saturated", 20000.0)):
        dcam, wins, dc, dR = _detector_disc(amp, 3)
        out[name] = (wins, dc, dR, _psf_options(DISC_NOISE, min_sigma_px=1e-6), dcam)
    return out, cam, frame


def frame_limb(frame, cam):
    from starnav.navigation.limb import (
        limb_points_from_segments,
        segments_centroid,
        sun_direction_in_image,
    )

    d = sun_direction_in_image(cam, frame.R_cam_to_inertial_measured,
                               frame.sun_direction_inertial, segments_centroid(frame.segments))
    return limb_points_from_segments(frame.segments, d, options=ChainOptions().limb)


def _measure() -> dict:
    cases, cam, frame = _cases()
    doc: dict = {}
    for name, (wins, c, R, (opt, models), camera) in cases.items():
        fine = refine_limb(wins, c, R, options=opt, models=models, camera=camera, phase_rad=1.0)
        doc[name] = {"uv": fine.uv.tolist(), "sigma_px": fine.sigma_px.tolist(),
                     "fit_sigma_px": fine.fit_sigma_px.tolist(),
                     "saturated": fine.saturated.tolist()}
    opt, models = _psf_options(NOISE)
    m = process_frame(frame, cam, options=ChainOptions(refine=opt, refine_models=models),
                      rng=np.random.default_rng(1))
    doc["chain-detector-psf"] = {"position": m.position.tolist(), "n_refined": len(m.refined),
                                 "covariance_diag": np.diag(m.covariance).tolist()}
    return doc


@pytest.fixture(scope="module")
def measured() -> dict:
    return _measure()


@pytest.fixture(scope="module")
def pins() -> dict:
    return json.loads(PINS.read_text())


@pytest.mark.parametrize("name", ["bench-gauss-fitted", "bench-gauss-known-noise",
                                  "bench-detector-psf", "disc-well-exposed", "disc-saturated"])
def test_refined_points_and_sigmas_match_the_per_window_fit(measured, pins, name):
    got, want = measured[name], pins[name]
    assert got["saturated"] == want["saturated"]
    uv, uv0 = np.asarray(got["uv"]), np.asarray(want["uv"])
    assert uv.shape == uv0.shape and uv.shape[0] >= 12
    moved, sat = np.hypot(*(uv - uv0).T), np.asarray(want["saturated"], bool)
    assert np.all(moved[~sat] < POINT_TOL_PX)
    assert np.all(moved[sat] < SATURATED_POINT_TOL * np.asarray(want["fit_sigma_px"])[sat])
    np.testing.assert_allclose(got["sigma_px"], want["sigma_px"], rtol=SIGMA_TOL)
    # the fit's own sigma (before the model errors and the floor are added)
    np.testing.assert_allclose(got["fit_sigma_px"], want["fit_sigma_px"], rtol=SIGMA_TOL)


def test_the_fix_matches_the_per_window_fit(measured, pins):
    got, want = measured["chain-detector-psf"], pins["chain-detector-psf"]
    assert got["n_refined"] == want["n_refined"]
    p, p0 = np.asarray(got["position"]), np.asarray(want["position"])
    assert np.linalg.norm(p - p0) < FIX_TOL * np.linalg.norm(p0)
    np.testing.assert_allclose(got["covariance_diag"], want["covariance_diag"], rtol=0.02)


if __name__ == "__main__":
    from starnav.atomic import atomic_write_text

    atomic_write_text(PINS, json.dumps(_measure(), indent=1) + "\n")
    print(f"wrote {PINS}")
