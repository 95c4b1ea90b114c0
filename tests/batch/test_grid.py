"""Grid parsing, validation and render sharing (no rendering)."""

from __future__ import annotations

import pytest

from starnav.batch.grid import expand, parse_grid, render_groups, split_values
from starnav.errors import ConfigError


def test_values_are_numbers_lists_and_split_outside_brackets():
    assert split_values("1,[2, 3],'a,b'") == ["1", "[2, 3]", "'a,b'"]
    (a,) = parse_grid(["detector.exposure_time_s=1.5e-5,1e-4,2"])
    assert a.values == (1.5e-5, 1e-4, 2)  # 1e-4 is a float, not YAML 1.1's string
    assert all(isinstance(v, int | float) for v in a.values)


def test_product_order_and_linked_axes():
    axes = parse_grid(["detector.exposure_time_s+detector.readout.segments.thresholds_dn="
                       "[0.2,[2048]],[1.5e-5,[200]]", "moon.albedo_scale=1,0.5"])
    pts = expand({}, axes)
    assert len(pts) == 4  # linked: 2 (not 4) x 2
    got = [(p.scenario.detector.exposure_time_s, p.scenario.detector.readout.segments
            .thresholds_dn, p.scenario.moon.albedo_scale) for p in pts]
    assert got == [(0.2, (2048,), 1.0), (0.2, (2048,), 0.5), (1.5e-5, (200,), 1.0),
                   (1.5e-5, (200,), 0.5)]


def test_renders_are_shared_downstream_only():
    pts = expand({}, parse_grid(["detector.exposure_time_s=1e-5,1e-3",
                                 "moon.albedo_scale=1,0.25",
                                 "navigation.ransac.threshold_px=1,2"]))
    assert len(render_groups(pts)) == 1  # albedo_scale multiplies the reflectance: downstream
    assert sorted({p.albedo_factor for p in pts}) == [0.25, 1.0]
    # for every model, Hapke included (its *albedo* enters non-linearly, its scale does not)
    pts = expand({}, parse_grid(["moon.photometry.model=hapke",
                                 "moon.albedo_scale=1,0.5"]))
    assert len(render_groups(pts)) == 1 and {p.albedo_factor for p in pts} == {1.0, 0.5}
    pts = expand({}, parse_grid(["moon.albedo=0.1,0.2"]))
    assert len(render_groups(pts)) == 2 and {p.albedo_factor for p in pts} == {1.0}
    pts = expand({}, parse_grid(["render.spp=4,8", "detector.exposure_time_s=1e-5,1e-3"]))
    assert [len(g) for g in render_groups(pts).values()] == [2, 2]


def test_base_overrides_apply_before_the_grid():
    pts = expand({}, parse_grid(["detector.exposure_time_s=1e-3"]),
                 overrides=["detector.exposure_time_s=5e-3", "seed=3"])
    assert pts[0].scenario.detector.exposure_time_s == 1e-3 and pts[0].scenario.seed == 3


@pytest.mark.parametrize(("items", "match"), [
    ([], "at least one --grid"),
    (["detector.exposure_time_s="], "empty"),
    (["detector.exposure_time_s"], "KEY=V1"),
    (["=1,2"], "dotted scenario key"),
    (["seed=1", "seed=2"], "each key once"),
    (["a+a=[1,1]"], "distinct keys"),
    (["detector.exposure_time_s+seed=1,2"], "a list of 2 values"),
])
def test_bad_grids(items, match):
    with pytest.raises(ConfigError, match=match):
        expand({}, parse_grid(items))


def test_unknown_key_suggests_the_right_one():
    with pytest.raises(ConfigError) as e:
        expand({}, parse_grid(["detector.exposure_time=1e-3,2e-3"]))
    assert "did you mean detector.exposure_time_s" in str(e.value)


def test_bad_value_names_the_point_and_the_field():
    with pytest.raises(ConfigError) as e:
        expand({}, parse_grid(["detector.exposure_time_s=1e-3,-1"]))
    msg = str(e.value)
    assert "point 1" in msg and "detector.exposure_time_s" in msg and "-1" in msg


def test_exposure_study_preset_file_round_trips(tmp_path):
    """What `starnav init --preset exposure-study` writes loads back as the same scenario and
    expands to the paper's four exposures."""
    import yaml

    from starnav.batch.presets import (
        PAPER_EXPOSURES_S,
        exposure_study_header,
        exposure_study_scenario,
        get_preset,
    )
    from starnav.config import load_scenario, scenario_to_dict

    p = tmp_path / "exposure-study.yaml"
    p.write_text(exposure_study_header() + yaml.safe_dump(exposure_study_scenario(),
                                                          sort_keys=False))
    sc = load_scenario(p)
    assert scenario_to_dict(sc) == exposure_study_scenario()
    assert sc.navigation.refine.enabled is False and sc.trajectory is not None
    pts = expand(sc, parse_grid(get_preset("exposure-study").grid))
    assert [q.scenario.detector.exposure_time_s for q in pts] == list(PAPER_EXPOSURES_S)
    assert len(render_groups(pts)) == 1
    assert "--preset exposure-study" in exposure_study_header()


def test_every_scenario_section_is_upstream_or_downstream_of_the_renderer():
    """A section in neither list would be dropped from the shared render (its defaults
    rendered instead): a small body's sweep would render the Moon."""
    from starnav.batch.grid import DOWNSTREAM_SECTIONS, UPSTREAM_SECTIONS
    from starnav.config import Scenario

    assert not set(UPSTREAM_SECTIONS) & set(DOWNSTREAM_SECTIONS)
    assert set(UPSTREAM_SECTIONS) | set(DOWNSTREAM_SECTIONS) == set(Scenario.model_fields)


def test_a_small_body_point_renders_its_own_body():
    """The render a point's group uses is the point's target and spacecraft; the stars are
    drawn downstream (one render for star fields on and off)."""
    from starnav.batch.grid import render_config
    from starnav.config import scenario_from_dict

    base = {"target": {"kind": "ellipsoid"}, "spacecraft": {"mass_kg": 50.0},
            "geometry": {"range_km": 3.0}}
    (p,) = expand(base, parse_grid(["detector.exposure_time_s=1e-5"]))
    cfg, _ = render_config(p.scenario)
    rendered = scenario_from_dict(cfg)
    assert rendered.target is not None and rendered.target.kind == "ellipsoid"
    assert rendered.spacecraft.mass_kg == 50.0
    pts = expand(base, parse_grid(["stars.enabled=true,false", "target.radii_km=[0.3,0.2,0.1],"
                                   "[0.4,0.2,0.1]"]))
    assert len(pts) == 4 and len(render_groups(pts)) == 2
