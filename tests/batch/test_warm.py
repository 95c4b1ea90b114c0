"""The worker preload's data (issue 18): what ``warm_data`` reads is what the first task of
the exposure study (the paper's sweep, stars on, the default Moon and tracker) looks up, so that
a warm worker's first task finds it in its caches."""

from __future__ import annotations

from starnav.batch.presets import get_preset
from starnav.batch.warm import warm_data
from starnav.config import build_camera, scenario_from_dict
from starnav.dem import limb
from starnav.simulate import scene_from_scenario
from starnav.stars import identify
from starnav.stars.catalogue import hipparcos, jyear_from_tdb


def test_warmed_data_are_the_exposure_studys_cache_entries():
    out = warm_data()
    assert set(out) == {"limb_topography", "hipparcos", "star_index"}
    sc = scenario_from_dict(get_preset("exposure-study").scenario())
    assert sc.stars.enabled
    # the lookups of its tasks, with the epochs of its real frames
    scene = scene_from_scenario(sc)
    years = {round(jyear_from_tdb(float(t))) for t in (scene.epochs[0], scene.epochs[-1])}
    misses = identify._index.cache_info().misses
    for year in years:
        identify.star_index(hipparcos(), identify.IdentifyOptions().index_v_limit,
                            build_camera(sc.camera).fov_diagonal, float(year))
    assert identify._index.cache_info().misses == misses, "the pair table was not warmed"
    lm = limb._BY_CONFIG.misses
    limb.limb_topography_for(sc.moon.dem)
    assert limb._BY_CONFIG.misses == lm, "the limb topography was not warmed"
