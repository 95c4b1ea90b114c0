"""Stars in the frame: electrons conserved through the PSF, PSF centroid on the projected
position, occultation by the body, nothing changed when stars are off."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import norm

from starnav.camera import Camera
from starnav.config import Scenario, scenario_from_dict
from starnav.detector import DetectorConfig, PointSources, expose
from starnav.detector.optics import point_source_image
from starnav.detector.schema import AberrationPsfConfig
from starnav.errors import ConfigError
from starnav.geometry import FrameGeometry, look_rotation
from starnav.spectra import sensor_response
from starnav.stars import StarsConfig, frame_stars
from starnav.stars.catalogue import StarCatalogue
from tests.detector.conftest import quiet_config

#: Centroid tolerance [px] (issue 17).
CENTROID_TOL_PX = 0.05


def _centroid(img: np.ndarray, u: float, v: float, half: int = 10) -> tuple[float, float]:
    yy, xx = np.mgrid[:img.shape[0], :img.shape[1]]
    m = (np.abs(xx - u) <= half) & (np.abs(yy - v) <= half)
    w = np.where(m, img, 0.0).astype(float)
    return float((w * xx).sum() / w.sum()), float((w * yy).sum() / w.sum())


def test_psf_conserves_electrons_and_loses_the_gaussian_tail_at_the_edge():
    """Gaussian PSF (no defocus, sigma 0.8 px, uniform field): a star 0.3 px inside the left
    edge loses the fraction Phi((-0.5 - u) / sigma) of its electrons off the array (closed
    form); an interior star loses nothing."""
    cam = Camera.preset("aa-str", width=64, height=64)
    cfg = AberrationPsfConfig(defocus_radius_px=0.0, defocus_radius_edge_px=0.0, sigma_px=0.8,
                              sigma_radial_edge_px=0.8, sigma_tangential_edge_px=0.8)
    src = PointSources(np.array([-0.2, 30.4]), np.array([20.3, 40.7]), np.ones(2))
    img, lost = point_source_image((64, 64), src, np.array([1000.0, 500.0]), cam, cfg)
    assert img.sum(dtype=np.float64) + lost == pytest.approx(1500.0, rel=1e-6)
    expected_lost = 1000.0 * norm.cdf((-0.5 - (-0.2)) / 0.8)
    assert lost == pytest.approx(expected_lost, rel=5e-3), (lost, expected_lost)
    interior = img[30:52, 20:42].sum(dtype=np.float64)
    assert interior == pytest.approx(500.0, rel=1e-6)


@pytest.mark.parametrize("uv", [(511.5, 511.5), (100.23, 880.71), (900.6, 60.35),
                                (1000.9, 1010.1)])
def test_psf_centroid_is_the_projected_position(uv):
    """AA-STR field-varying PSF (defocus disc, elliptical Gaussian growing to the corner):
    the centroid of an isolated star's electrons equals its position within 0.05 px."""
    cam = Camera.preset("aa-str")
    cfg = quiet_config(optics={"aberration": {"enabled": True}})
    src = PointSources(np.array([uv[0]]), np.array([uv[1]]), np.array([1e6]))
    e = expose(np.zeros((cam.height, cam.width), np.float32), cam, cfg, exposure_time=0.2,
               point_sources=src)
    cu, cv = _centroid(e.electrons, *uv)
    assert math.hypot(cu - uv[0], cv - uv[1]) < CENTROID_TOL_PX
    # charge: rate x t, nothing lost this far from the edges
    assert e.electrons.sum(dtype=np.float64) == pytest.approx(2e5, rel=1e-5)
    assert e.ledger["photoelectrons_e"] == pytest.approx(2e5)


def _geometry(cam: Camera, boresight: np.ndarray, moon_at: np.ndarray | None,
              range_m: float = 3e8) -> FrameGeometry:
    R = look_rotation(np.array([0.0, 0.0, 1.0]), boresight)
    pos = -range_m * moon_at if moon_at is not None else 1e12 * boresight
    return FrameGeometry(camera_position=pos, R_cam_to_inertial=R,
                         sun_position=np.array([1.5e11, 0.0, 0.0]))


def _catalogue(dirs: np.ndarray, v: list[float]) -> StarCatalogue:
    ra = np.arctan2(dirs[:, 1], dirs[:, 0])
    dec = np.arcsin(dirs[:, 2])
    n = len(v)
    return StarCatalogue(np.arange(1, n + 1), ra, dec, np.zeros(n), np.zeros(n), np.array(v),
                         np.zeros(n))


def test_distorted_star_lands_where_the_camera_projects_it():
    """A lens with barrel and decentring distortion (2.3 px at the star): the star is drawn in
    the pinhole image and the chain's distortion resampling carries its PSF to the distorted
    projection (the ``pixel_px`` of the true star list) within 0.05 px. (With 11 px of
    distortion the chain's bilinear resampling itself moves the centroid by ~0.06 px.)"""
    cam = Camera.preset("aa-str", width=256, height=256, k1=-10.0, p1=5e-3)
    det = quiet_config(optics={"aberration": {"enabled": True},
                               "distortion": {"enabled": True}})
    bore = np.array([0.0, 0.0, 1.0])
    R = look_rotation(np.array([0.0, 0.0, 1.0]), bore)
    star_cam = cam.unproject(np.array([[40.3, 210.8]]))[0]
    cat = _catalogue((R @ star_cam)[None, :], [2.0])
    geom = _geometry(cam, bore, None)
    # astrometric places: the star lands exactly where it was put (aberration moves it ~20")
    f = frame_stars(geom, cam, StarsConfig(enabled=True, aberration=False),
                    sensor_response("aa-str"), exposure_time=0.2, detector=det, catalogue=cat)
    assert len(f.visible()) == 1
    pix = f.pixel_px[0]
    assert np.hypot(*(pix - f.pinhole_px[0])) > 1.0  # distortion really moves it
    np.testing.assert_allclose(pix, [40.3, 210.8], atol=1e-6)
    e = expose(np.zeros((256, 256), np.float32), cam, det, exposure_time=0.2,
               point_sources=f.point_sources())
    cu, cv = _centroid(e.electrons, *pix)
    assert math.hypot(cu - pix[0], cv - pix[1]) < CENTROID_TOL_PX


def test_star_behind_the_moon_is_not_in_the_frame():
    """Two V = 2 stars: one behind the Moon's disc, one beside it. The true list keeps only
    the free one, and the exposure has no star light at the hidden one's position."""
    cam = Camera.preset("aa-str", width=256, height=256)
    bore = np.array([1.0, 0.0, 0.0])
    geom = _geometry(cam, bore, bore, range_m=4e7)  # Moon 2.5 deg radius (~124 px), centred
    R = geom.R_cam_to_inertial
    hidden = R @ cam.unproject(np.array([[140.0, 120.0]]))[0]
    free = R @ cam.unproject(np.array([[20.0, 30.0]]))[0]
    cat = _catalogue(np.stack([hidden, free]), [2.0, 2.0])
    det = quiet_config(optics={"aberration": {"enabled": True}})
    f = frame_stars(geom, cam, StarsConfig(enabled=True), sensor_response("aa-str"),
                    exposure_time=0.2, detector=det, catalogue=cat)
    assert f.occulted.tolist() == [True, False]
    vis = f.visible()
    assert vis.hip.tolist() == [2]
    e = expose(np.zeros((256, 256), np.float32), cam, det, exposure_time=0.2,
               point_sources=f.point_sources())
    assert e.electrons[110:131, 130:151].max() == 0.0
    assert e.electrons[20:41, 10:31].sum() == pytest.approx(vis.electrons[0], rel=1e-5)


def test_stars_off_changes_nothing_and_on_adds_the_field():
    cam = Camera.preset("aa-str", width=128, height=128)
    le = np.zeros((128, 128), np.float32)
    le[40:60, 40:60] = 1e14
    cfg = DetectorConfig()
    a = expose(le, cam, cfg, seed=3, exposure_time=0.01)
    b = expose(le, cam, cfg, seed=3, exposure_time=0.01, point_sources=None)
    c = expose(le, cam, cfg, seed=3, exposure_time=0.01,
               point_sources=PointSources(np.array([100.2]), np.array([20.7]),
                                          np.array([1e7])))
    assert np.array_equal(a.dn, b.dn) and a.ledger == b.ledger
    assert c.dn[15:27, 94:107].sum() > a.dn[15:27, 94:107].sum() + 1000


def test_the_scenario_switch_is_off_by_default_and_documented():
    assert Scenario().stars.enabled is False
    for name, field in StarsConfig.model_fields.items():
        assert field.description, f"stars.{name} has no description"
    sc = scenario_from_dict({"stars": {"enabled": True, "magnitude_limit": 5.0}})
    assert sc.stars.magnitude_limit == 5.0
    with pytest.raises(ConfigError, match="magnitude_limit"):
        scenario_from_dict({"stars": {"magnitude_limit": 40}})
    with pytest.raises(ConfigError):
        scenario_from_dict({"stars": {"enabeld": True}})


def test_a_real_field_at_200_ms_gives_ke_stars():
    """The Hipparcos field around Orion's belt through the AA-STR at 200 ms: the V ~ 6 stars
    give 8-16 ke- (REFERENCE.md s6), the belt stars ~1e6 e-."""
    cam = Camera.preset("aa-str")
    alnilam = np.array([math.cos(math.radians(-1.2)) * math.cos(math.radians(84.053)),
                        math.cos(math.radians(-1.2)) * math.sin(math.radians(84.053)),
                        math.sin(math.radians(-1.2))])
    geom = _geometry(cam, alnilam, None)
    f = frame_stars(geom, cam, StarsConfig(enabled=True), sensor_response("aa-str"),
                    exposure_time=0.2).visible()
    assert len(f) > 20
    near6 = (f.v > 5.8) & (f.v < 6.2) & (np.abs(f.b_v) < 0.7)
    assert near6.any()
    assert np.all((f.electrons[near6] > 6e3) & (f.electrons[near6] < 2e4))
    assert 26311 in f.hip.tolist()
