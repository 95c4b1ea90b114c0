"""Scenario configuration: strict validation, overrides and clear errors."""

from __future__ import annotations

import math

import pytest
import yaml

from starnav.config import (
    Scenario,
    build_camera,
    load_scenario,
    scenario_from_dict,
    scenario_to_dict,
    write_resolved,
)
from starnav.errors import ConfigError, DataFileError


def test_defaults_are_the_aa_str_at_60000_km():
    sc = Scenario()
    cam = build_camera(sc.camera)
    assert (cam.width, cam.height, cam.focal_length) == (1024, 1024, 50.7e-3)
    assert sc.geometry.range_km == 60_000.0
    # the real Moon by default: LOLA terrain, LROC albedo, ROLO-calibrated Hapke, lunar colour
    assert sc.moon.shape == "dem"
    assert (sc.moon.dem.source, sc.moon.dem.albedo.source) == ("lola", "lroc")
    assert sc.moon.photometry.model == "hapke"
    assert sc.moon.photometry.preset == "rolo-calibrated"
    assert sc.moon.photometry.spectral_shape == "rolo"
    assert sc.moon.albedo is None


def test_unknown_key_is_rejected_with_its_name():
    with pytest.raises(ConfigError, match="camra"):
        scenario_from_dict({"camra": {}})
    with pytest.raises(ConfigError, match="moon.radius"):
        scenario_from_dict({"moon": {"radius": 1.0}})


@pytest.mark.parametrize("data,field", [
    ({"moon": {"albedo": -0.1}}, "moon.albedo"),
    ({"moon": {"albedo": 5}}, "moon.albedo"),
    ({"moon": {"photometry": {"preset": "helfenstein"}}}, "moon.photometry.preset"),
    ({"moon": {"dem": {"albedo": {"source": "x.tif", "quantity": "normal_albedo",
                                  "contrast_exponent": 0.5}}}}, "moon.dem.albedo"),
    ({"moon": {"photometry": {"model": "phong"}}}, "moon.photometry"),
    ({"camera": {"focal_length_mm": 0}}, "camera.focal_length_mm"),
    ({"geometry": {"phase_angle_deg": 200}}, "geometry.phase_angle_deg"),
    ({"moon": {"photometry": {"model": "hapke", "params": {"b": 1.5}}}}, "moon.photometry"),
    ({"moon": {"photometry": {"model": "lambert", "params": {"b": 0.2}}}}, "moon.photometry"),
])
def test_bad_values_name_the_field_and_value(data, field):
    with pytest.raises(ConfigError) as info:
        scenario_from_dict(data)
    assert info.value.field == field
    assert str(info.value).startswith(field)


def test_unknown_model_lists_known_models():
    with pytest.raises(ConfigError, match="lommel_seeliger"):
        scenario_from_dict({"moon": {"photometry": {"model": "phong"}}})


def test_overrides_parse_yaml_values():
    sc = scenario_from_dict({}, ["moon.albedo=0.2", "geometry.moon_offset_px=[10, -5]",
                                 "render.spp=4", "camera.preset=aa-str"])
    assert sc.moon.albedo == 0.2
    assert sc.geometry.moon_offset_px == (10.0, -5.0)
    assert sc.render.spp == 4
    with pytest.raises(ConfigError, match="--set"):
        scenario_from_dict({}, ["moon.albedo"])


def test_models_are_frozen():
    sc = Scenario()
    with pytest.raises(Exception):  # noqa: B017 - pydantic's frozen-instance error
        sc.seed = 3  # type: ignore[misc]


def test_resolved_round_trip(tmp_path):
    sc = scenario_from_dict({"moon": {"albedo": 0.3}, "seed": 7})
    p = write_resolved(sc, tmp_path)
    again = load_scenario(p)
    assert again == sc
    assert scenario_to_dict(again)["seed"] == 7
    assert not list(tmp_path.glob(".*tmp"))  # no temporary file left behind


def test_missing_and_invalid_files(tmp_path):
    with pytest.raises(DataFileError, match="does not exist"):
        load_scenario(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("camera: [unclosed")
    with pytest.raises(ConfigError, match="YAML"):
        load_scenario(bad)


def test_init_example_validates(tmp_path):
    from typer.testing import CliRunner

    from starnav.cli.main import app

    out = tmp_path / "s.yaml"
    res = CliRunner().invoke(app, ["init", str(out)])
    assert res.exit_code == 0, res.output
    assert load_scenario(out) == Scenario()
    assert yaml.safe_load(out.read_text())["camera"]["preset"] == "aa-str"
    res = CliRunner().invoke(app, ["validate", str(out), "--set", "moon.albedo=-1"])
    assert res.exit_code == 2
    assert "moon.albedo" in res.output


@pytest.mark.parametrize("dem,source,albedo", [
    ({}, "lola", "lroc"),
    ({"mesh": {"edge_px": 2.0}}, "lola", "lroc"),           # a tweak keeps the real Moon
    ({"albedo": {"normalize_mean": 0.1}}, "lola", "lroc"),
    ({"source": "procedural"}, "procedural", "procedural"),
    ({"source": "my_dem.lbl"}, "my_dem.lbl", None),          # a user's DEM: uniform albedo
    ({"albedo": None}, "lola", None),                        # explicit: no map
])
def test_a_partial_dem_section_keeps_the_real_moon_defaults(dem, source, albedo):
    cfg = scenario_from_dict({"moon": {"dem": dem}}).moon.dem
    assert cfg.source == source
    assert (None if cfg.albedo is None else cfg.albedo.source) == albedo
    # the same through a command-line override
    if dem == {"mesh": {"edge_px": 2.0}}:
        sc = scenario_from_dict({}, ["moon.dem.mesh.edge_px=2"])
        assert (sc.moon.dem.source, sc.moon.dem.albedo.source) == ("lola", "lroc")


# --------------------------------------------------------------------------- SI view
def test_si_suffix_factors_agree_with_astropy():
    import astropy.units as u

    from starnav.config_base import SI_SUFFIXES

    units = {"_km_s": (u.km / u.s, u.m / u.s), "_deg_s": (u.deg / u.s, u.rad / u.s),
             "_m_s": (u.m / u.s, u.m / u.s), "_m2_s3": (u.m**2 / u.s**3, u.m**2 / u.s**3),
             "_w_m2": (u.W / u.m**2, u.W / u.m**2), "_km": (u.km, u.m), "_mm": (u.mm, u.m),
             "_um": (u.um, u.m), "_m": (u.m, u.m), "_au": (u.au, u.m), "_deg": (u.deg, u.rad),
             "_arcsec": (u.arcsec, u.rad), "_days": (u.day, u.s), "_s": (u.s, u.s),
             "_ms": (u.ms, u.s), "_us": (u.us, u.s), "_k": (u.K, u.K),
             "_deg_rt_h": (u.deg / u.h**0.5, u.rad / u.s**0.5),
             "_deg_h": (u.deg / u.h, u.rad / u.s)}
    for suffix, conv in SI_SUFFIXES.items():
        if conv is None:
            continue
        if suffix == "_c":
            assert (20.0 * u.deg_C).to(u.K, equivalencies=u.temperature()).value \
                == pytest.approx(20.0 * conv[0] + conv[1], rel=1e-15)
            continue
        src, dst = units[suffix]
        assert conv == (pytest.approx(src.to(dst), rel=1e-15), 0.0), suffix


def test_the_si_view_drops_suffixes_and_converts():
    from starnav.config_base import SIView

    sc = Scenario.model_validate({"detector": {"smear": {"rolling_shutter": {"row_time_us": 174}},
                                               "charge": {"dark_current": {"temperature_c": -10}}},
                                  "pointing": {"roll": "fixed", "roll_deg": 90}})
    si = sc.to_si()
    assert isinstance(si.detector, SIView)
    assert si.detector.smear.rolling_shutter.row_time == pytest.approx(1.74e-4, rel=1e-15)
    assert si.detector.charge.dark_current.temperature == pytest.approx(263.15, rel=1e-15)
    assert si.detector.readout.timing.a == pytest.approx(8e-3)        # a_ms default 8
    assert si.detector.charge.dark_current.rate_e_per_s == 590.0     # counting unit kept
    assert si.pointing.roll == "fixed" and si.pointing.roll_angle == pytest.approx(math.pi / 2)
    assert si.detector.exposure_time == sc.detector.exposure_time_s  # SI already: renamed only
    with pytest.raises(AttributeError, match="row_time"):
        si.detector.smear.rolling_shutter.row_time_us  # noqa: B018
    with pytest.raises(AttributeError, match="read-only"):
        si.detector.exposure_time = 1.0
    # a view travels to worker processes: pickled and copied whole, equal and read-only after
    import copy
    import pickle

    for back in (pickle.loads(pickle.dumps(si)), copy.deepcopy(si)):
        assert back == si
        assert back.detector.readout.timing.a == si.detector.readout.timing.a
        with pytest.raises(AttributeError, match="read-only"):
            back.detector.exposure_time = 1.0
