"""Target bodies behind one interface (issue 14): the IAU rotation model against its closed
form, and a triaxial body rendered through the same renderer whose silhouette is the
ellipsoid's exact projected limb (the navigation metrics' conic) in a rotated pose."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
from matplotlib.path import Path as MplPath

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")

from starnav.bodies import EllipsoidConfig, Moon, TriaxialBody, ellipsoid_mesh, iau_orientation
from starnav.constants import DAY


def test_iau_orientation_pole_and_spin():
    """R e_z is the pole (cos d cos a, cos d sin a, sin d); after dt the prime meridian has
    turned by W_dot dt about it; R is a proper rotation."""
    a, d, w0, wd = math.radians(90.53), math.radians(-66.30), 0.3, math.radians(712.143)
    t = np.array([0.0, 1234.5, 0.25 * DAY])
    R = iau_orientation(t, a, d, w0, wd)
    pole = np.array([math.cos(d) * math.cos(a), math.cos(d) * math.sin(a), math.sin(d)])
    assert np.allclose(R @ [0, 0, 1], pole, atol=1e-14)
    assert np.allclose(R @ np.swapaxes(R, -1, -2), np.eye(3), atol=1e-14)
    assert np.allclose(np.linalg.det(R), 1.0)
    x0, x1 = R[0] @ [1, 0, 0], R[2] @ [1, 0, 0]
    turned = math.atan2(np.dot(np.cross(x0, x1), pole), np.dot(x0, x1))
    assert turned == pytest.approx(math.remainder(wd * 0.25, 2 * math.pi), abs=1e-12)
    # W0: the prime meridian at J2000 is W0 east of the node of the equator on the ICRF equator
    node = np.cross([0, 0, 1], pole)
    node /= np.linalg.norm(node)
    assert math.atan2(np.dot(np.cross(node, x0), pole), np.dot(node, x0)) \
        == pytest.approx(w0, abs=1e-12)


def test_ellipsoid_mesh_is_on_the_ellipsoid_with_exact_normals():
    r = (300.0, 150.0, 100.0)
    m = ellipsoid_mesh(r, 3)
    q = np.sum((m.vertices / r) ** 2, axis=1)
    assert np.allclose(q, 1.0, atol=1e-12)
    grad = m.vertices / np.square(r)
    assert np.allclose(m.normals, grad / np.linalg.norm(grad, axis=1, keepdims=True))


def test_the_moon_body_matches_its_section():
    from starnav.bodies.schema import MoonConfig

    moon = Moon(MoonConfig(shape="sphere", radius_km=1737.4))
    assert moon.radii_m == (1737400.0,) * 3 and moon.reference_radius_m == 1737400.0
    with pytest.raises(Exception, match="moon_frame"):
        Moon(frame="XY")


def test_a_rotated_triaxial_body_renders_with_its_exact_limb():
    """Itokawa-sized ellipsoid, spun to an epoch by its IAU model, seen from 4 km at phase 0:
    the rendered Moon-mask pixels are the pixel centres inside the ellipsoid's exact projected
    limb (``christian_robinson.ellipsoid_limb_points``), up to a few boundary pixels."""
    from starnav.camera import Camera
    from starnav.geometry import FrameGeometry, look_rotation
    from starnav.navigation.christian_robinson import ellipsoid_limb_points, shape_transform
    from starnav.renderer.render import MoonRenderer, RenderSettings
    from starnav.spectra import (
        SensorResponseConfig,
        SunConfig,
        sensor_response_from_config,
        solar_spectrum_from_config,
    )

    body = TriaxialBody(EllipsoidConfig(mesh_subdivisions=6))
    R_body = body.orientation(np.array([0.37 * DAY]))[0]
    cam = Camera.preset("aa-str", width=160, height=160, focal_length=0.02)
    view = np.array([0.3, -0.5, 0.81])
    view /= np.linalg.norm(view)
    pos = 4000.0 * view
    geom = FrameGeometry(camera_position=pos, R_cam_to_inertial=look_rotation(
        np.array([0.0, 0.0, 1.0]), -view), sun_position=1.496e11 * view,
        R_body_to_inertial=R_body, body_radius=body.reference_radius_m)
    renderer = MoonRenderer(cam, sensor_response_from_config(SensorResponseConfig()),
                            solar_spectrum_from_config(SunConfig()), body.render_model(),
                            RenderSettings(spp=4))
    img = renderer.render(geom, seed=1)
    mask = img.mask
    B = shape_transform(body.radii_m, geom.R_cam_to_inertial.T @ R_body)
    limb = ellipsoid_limb_points(cam, geom.moon_centre_camera(), B, n=4000, distort=False)
    vv, uu = np.mgrid[0:cam.height, 0:cam.width]
    inside = MplPath(limb).contains_points(np.column_stack([uu.ravel(), vv.ravel()]))
    inside = inside.reshape(mask.shape)
    perimeter = float(np.sum(np.linalg.norm(np.diff(limb, axis=0), axis=1)))
    assert inside.sum() > 2000  # a body of ~50-100 px across
    differ = int(np.sum(inside != mask))
    assert differ <= 3 + 0.01 * perimeter, (differ, perimeter)
    # the silhouette is not the one the unrotated body would have
    B0 = shape_transform(body.radii_m, geom.R_cam_to_inertial.T)
    limb0 = ellipsoid_limb_points(cam, geom.moon_centre_camera(), B0, n=4000, distort=False)
    inside0 = MplPath(limb0).contains_points(np.column_stack([uu.ravel(), vv.ravel()]))
    assert np.sum(inside0.reshape(mask.shape) != mask) > 20 * max(differ, 1)
    # lit everywhere it is seen (phase 0): radiance wherever the mask is
    assert np.all(img.L[mask] > 0)


def test_a_small_body_scenario_goes_through_the_same_chain():
    """``target: {kind: ellipsoid}``: the same Simulator renders it, the same acquisitions read
    it, and the navigation chain fixes the camera with the body's own ellipsoid
    (``simulate.chain_options``). At 3 km the fix is within 5 % of the range (the window
    refinement is calibrated on the Moon, not on a 36 px body: its sigma is not trusted here,
    issue 16); with a sphere of the longest semi-axis instead it is off by several times more."""
    from starnav.config import scenario_from_dict
    from starnav.navigation.metrics import limb_point_errors
    from starnav.navigation.pipeline import process_frame
    from starnav.seeding import STAGE_NAVIGATION, generator
    from starnav.simulate import Simulator, body_from_scenario, chain_options

    sc = scenario_from_dict({
        "camera": {"width": 256, "height": 256, "focal_length_mm": 12.5},
        "render": {"spp": 8}, "target": {"kind": "ellipsoid"},
        "geometry": {"range_km": 3.0, "phase_angle_deg": 30.0, "sub_observer_lat_deg": 20.0,
                     "sub_observer_lon_deg": 40.0},
        "detector": {"exposure_time_s": 4e-6}})
    body = body_from_scenario(sc)
    assert isinstance(body, TriaxialBody) and body.radii_m == (267.5, 147.0, 104.5)
    sim = Simulator(sc)
    geom, img = sim.render(0)
    assert geom.body_radius == 267.5 and 3000 < img.mask.sum() < 6000
    acq, frame = sim.observe(img, geom)
    assert acq.plan_status == "ok" and 0 < acq.segments_exposure.dn.max() < 4095
    chain = chain_options(sc)
    assert chain.fix.radii_m == (267.5, 147.0, 104.5)
    m = process_frame(frame, sim.camera, options=chain,
                      rng=generator(sc.seed, STAGE_NAVIGATION, 0, 0))
    assert m.status == "ok"
    err = np.linalg.norm(np.asarray(m.position) - geom.camera_position)
    assert err < 0.05 * geom.range
    # the pixel-level limb points sit on the ellipsoid's true limb (segment-threshold bias)
    e = limb_point_errors(m.limb.uv[m.inliers], sim.camera, geom, body.radii_m)
    assert abs(float(np.mean(e))) < 1.5
    sphere = scenario_from_dict(sc.model_dump(mode="json"),
                                ["navigation.fix.moon_radii_km=[0.2675,0.2675,0.2675]"])
    m2 = process_frame(frame, sim.camera, options=chain_options(sphere),
                       rng=generator(sc.seed, STAGE_NAVIGATION, 0, 0))
    err2 = np.linalg.norm(np.asarray(m2.position) - geom.camera_position)
    assert err2 > 3 * err
