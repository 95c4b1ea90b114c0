"""The chain: seeding (fixed pattern vs temporal, order independence), registry, switches,
intermediate products, charge ledger, stage orders."""

from __future__ import annotations

import numpy as np
import pytest

from starnav.detector import CHAIN_ORDERS, EFFECTS, DetectorConfig, expose, get_effect
from starnav.detector.chain import chain_order
from starnav.detector.seeding import fixed_pattern_rng, temporal_rng
from starnav.errors import ConfigError, UnknownNameError

from .conftest import lambert_disc, quiet_config, small_camera


def _keep(**kw) -> DetectorConfig:
    data = {"debug": {"keep_stages": True}, "readout": {"timing": {"policy": "ignore"}}}
    data.update(kw)
    return DetectorConfig.model_validate(data)


def _disc(n: int = 64, peak: float = 2e16) -> np.ndarray:
    return lambert_disc(n, (30.0, 34.0), 14.0, peak)


def test_fixed_pattern_frozen_per_sensor_temporal_noise_per_frame(cam64):
    cfg = _keep()
    le = np.full((64, 64), 3e17, np.float32)
    a = expose(le, cam64, cfg, seed=5, frame_index=0, exposure_time=1e-3)
    b = expose(le, cam64, cfg, seed=5, frame_index=1, exposure_time=1e-3)
    # PRNU and dark pattern are deterministic maps: identical stage outputs
    assert np.array_equal(a.stages["prnu"], b.stages["prnu"])
    assert np.array_equal(a.stages["dark_current"], b.stages["dark_current"])
    # shot and read noise differ from frame to frame
    assert not np.array_equal(a.stages["shot_noise"], b.stages["shot_noise"])
    assert not np.array_equal(a.dn, b.dn)
    # same dataset seed and frame -> bit-identical DN (seeded regression, exact on purpose:
    # the chain is NumPy in double precision on a given radiance, the same on any CPU)
    again = expose(le, cam64, cfg, seed=5, frame_index=1, exposure_time=1e-3)
    assert np.array_equal(again.dn, b.dn)
    # another dataset seed: different noise and (no sensor_seed) a different sensor
    other = expose(le, cam64, cfg, seed=6, frame_index=1, exposure_time=1e-3)
    assert not np.array_equal(other.stages["prnu"], b.stages["prnu"])


def test_sensor_seed_pins_the_fixed_pattern_across_datasets(cam64):
    cfg = _keep(sensor_seed=42)
    le = np.full((64, 64), 3e17, np.float32)
    a = expose(le, cam64, cfg, seed=1, exposure_time=1e-3)
    b = expose(le, cam64, cfg, seed=2, exposure_time=1e-3)
    assert a.sensor_seed == b.sensor_seed == 42
    assert np.array_equal(a.stages["prnu"], b.stages["prnu"])
    assert not np.array_equal(a.stages["shot_noise"], b.stages["shot_noise"])


def test_frames_do_not_depend_on_processing_order(cam64):
    cfg = DetectorConfig()
    le = _disc()
    first = {i: expose(le, cam64, cfg, seed=9, frame_index=i).dn for i in (3, 1, 2)}
    second = {i: expose(le, cam64, cfg, seed=9, frame_index=i).dn for i in (1, 2, 3)}
    for i in (1, 2, 3):
        assert np.array_equal(first[i], second[i])


def test_streams_are_keyed_not_sequential():
    x = temporal_rng(3, 7, "read_noise").random(4)
    temporal_rng(3, 6, "read_noise").random(100)          # drawing others changes nothing
    assert np.array_equal(x, temporal_rng(3, 7, "read_noise").random(4))
    assert not np.array_equal(x, temporal_rng(3, 7, "shot_noise").random(4))
    assert not np.array_equal(fixed_pattern_rng(3, "prnu").random(4),
                              temporal_rng(3, 0, "prnu").random(4))
    with pytest.raises(ConfigError, match="seed = -1"):
        temporal_rng(-1, 0, "read_noise")


def test_registry_lists_known_names():
    with pytest.raises(UnknownNameError, match="unknown detector effect 'bloom'.*saturation"):
        get_effect("bloom")
    with pytest.raises(UnknownNameError, match="physical"):
        chain_order("alphabetical")
    for order in CHAIN_ORDERS.values():
        assert sorted(order) == sorted(EFFECTS)


def test_keep_stages_in_chain_order_and_electrons_after_the_pixel_stage():
    cfg = _keep(smear={"rolling_shutter": {"angular_rate_deg_s": (0.2, -0.1)},
                       "transfer": {"enabled": True}})
    f = expose(_disc(), small_camera(64, k1=-0.5), cfg, seed=1)
    names = list(f.stages)
    assert names == [n for n in CHAIN_ORDERS["physical"]] + ["adc"]
    assert np.array_equal(f.electrons, f.stages["saturation"])
    assert np.array_equal(f.signal, f.stages["read_noise"])
    assert np.array_equal(f.dn, f.stages["adc"])


@pytest.mark.parametrize("name", [n for n in CHAIN_ORDERS["physical"] if n != "photoelectrons"])
def test_every_effect_can_be_switched_off(name):
    """With the effect on its stage output differs from its input; off, it is absent."""
    cam = small_camera(64, k1=-0.5)
    on = {"smear": {"rolling_shutter": {"angular_rate_deg_s": (0.5, 0.3)},
                    "transfer": {"enabled": True}}}
    section = {
        "aberration_psf": {"optics": {"aberration": {"enabled": False}}},
        "distortion": {"optics": {"distortion": {"enabled": False}}},
        "rolling_shutter": {"smear": {"rolling_shutter": {"enabled": False}}},
        "stray_light": {"optics": {"stray_light": {"enabled": False}}},
        "ghosts": {"optics": {"ghosts": {"enabled": False}}},
        "transfer_smear": {"smear": {"transfer": {"enabled": False}}},
        "prnu": {"charge": {"prnu": {"enabled": False}}},
        "dark_current": {"charge": {"dark_current": {"enabled": False}}},
        "shot_noise": {"charge": {"shot_noise": {"enabled": False}}},
        "saturation": {"saturation": {"enabled": False}},
        "ipc": {"signal": {"ipc": {"enabled": False}}},
        "electrical_crosstalk": {"signal": {"electrical_crosstalk": {"enabled": False}}},
        "nonlinearity": {"signal": {"nonlinearity": {"enabled": False}}},
        "read_noise": {"signal": {"read_noise": {"enabled": False}}},
    }[name]
    le = _disc(peak=5e19)      # saturates: blooming and electrical crosstalk are active
    f_on = expose(le, cam, _keep(**on), seed=2, exposure_time=2e-3)
    order = list(f_on.stages)
    before = f_on.stages[order[order.index(name) - 1]]
    assert not np.array_equal(f_on.stages[name], before)
    merged = {**on, **{k: {**on.get(k, {}), **v} for k, v in section.items()}}
    f_off = expose(le, cam, _keep(**merged), seed=2, exposure_time=2e-3)
    assert name not in f_off.stages
    assert not np.array_equal(f_off.dn, f_on.dn)


def test_charge_ledger_balances_photoelectrons():
    """Photo-electrons = charge in the array + moved off it by the optics + drained + spilled
    out, with every deterministic charge-moving effect on (PSF, distortion, motion, halo,
    ghosts, saturation with blooming) and a disc cut by the array edge."""
    cam = small_camera(64, k1=-0.5)
    cfg = quiet_config(optics={"aberration": {"enabled": True}, "distortion": {"enabled": True},
                               "stray_light": {"enabled": True, "binning": 4},
                               "ghosts": {"enabled": True}},
                       smear={"rolling_shutter": {"enabled": True,
                                                  "angular_rate_deg_s": (0.3, 0.2)}},
                       saturation={"enabled": True, "blooming": {"spill_fraction": 0.2}})
    le = lambert_disc(64, (5.0, 30.0), 12.0, 1e19)
    f = expose(le, cam, cfg, exposure_time=1e-3)
    led = f.ledger
    total = f.electrons.sum(dtype=np.float64) + led["optics_lost_e"] + led["drained_e"] + \
        led["left_array_e"]
    assert led["left_array_e"] > 0 and led["drained_e"] > 0 and led["optics_lost_e"] > 0
    assert total == pytest.approx(led["photoelectrons_e"], rel=1e-5)


def test_paper_order_saturates_before_distortion(cam64):
    """In the paper's order distortion resamples the clipped plateau (values can pass F)."""
    cam = small_camera(64, focal_length=5e-3, k1=-0.3)
    le = lambert_disc(64, (44.0, 20.0), 12.0, 1e19)
    cfg = quiet_config(order="paper", optics={"distortion": {"enabled": True}},
                       saturation={"enabled": True})
    f = expose(le, cam, cfg, exposure_time=1e-3, keep_stages=True)
    assert list(f.stages)[:3] == ["photoelectrons", "saturation", "distortion"]
    assert f.stages["saturation"].max() <= 1e5
    assert f.electrons.max() > 1e5 * 1.001       # the area factor lifts the plateau
    phys = expose(le, cam, cfg.model_copy(update={"order": "physical"}), exposure_time=1e-3)
    assert phys.electrons.max() <= 1e5 * (1 + 1e-6)


# ------------------------------------------------------------- the deterministic part, reused
def _same_exposure(a, b) -> None:
    """Equal to the last bit: DN, charge, signal, readouts, ledger, stage copies."""
    assert np.array_equal(a.dn, b.dn) and np.array_equal(a.electrons, b.electrons)
    assert np.array_equal(a.signal, b.signal)
    assert a.ledger == b.ledger
    assert (a.segments is None) == (b.segments is None)
    if a.segments is not None:
        assert np.array_equal(a.segments.values, b.segments.values)
        assert np.array_equal(a.segments.row, b.segments.row)
    assert len(a.windows) == len(b.windows)
    assert all(np.array_equal(x.dn, y.dn) for x, y in zip(a.windows, b.windows, strict=True))
    assert list(a.stages) == list(b.stages)
    assert all(np.array_equal(a.stages[k], b.stages[k]) for k in a.stages)


@pytest.mark.parametrize("order", ["physical", "paper"])
def test_second_acquisition_from_the_mean_charge_equals_a_full_run(order):
    """A second acquisition of the same radiance that starts from the first one's frame before
    shot noise (MeanCharge) is bit for bit a full run of the chain with its own seed: every
    effect on, stars added, both stage orders, stage copies kept (a seeded regression test:
    exact equality)."""
    from starnav.detector.optics import PointSources

    cam = small_camera(64, k1=-0.3)
    cfg = DetectorConfig.model_validate({
        "order": order, "debug": {"keep_stages": True}, "sensor_seed": 9,
        "readout": {"timing": {"policy": "ignore"}},
        "smear": {"rolling_shutter": {"enabled": True, "angular_rate_deg_s": (0.3, 0.2)}}})
    le = _disc(peak=5e17)
    stars = PointSources(u=np.array([5.0, 50.2]), v=np.array([8.5, 55.0]),
                         rate=np.array([3e6, 8e5]))
    first = expose(le, cam, cfg, seed=1, frame_index=4, exposure_time=2e-3,
                   point_sources=stars, keep_mean_charge=True)
    mean = first.mean_charge
    assert mean is not None and not mean.image.flags.writeable
    assert chain_order(order)[mean.position] == "shot_noise"
    wins = [(10, 10, 12, 12), (40, 30, 8, 16)]
    reused = expose(le, cam, cfg, seed=77, frame_index=4, exposure_time=2e-3, windows=wins,
                    point_sources=stars, mean_charge=mean)
    full = expose(le, cam, cfg, seed=77, frame_index=4, exposure_time=2e-3, windows=wins,
                  point_sources=stars)
    _same_exposure(reused, full)
    assert not np.array_equal(reused.dn, first.dn)   # its own noise
    assert reused.mean_charge is None and full.mean_charge is None
    # the first acquisition is unchanged by keeping its mean charge
    _same_exposure(first, expose(le, cam, cfg, seed=1, frame_index=4, exposure_time=2e-3,
                                 point_sources=stars))


def test_a_mean_charge_of_other_inputs_is_refused():
    cam = small_camera(64)
    cfg = DetectorConfig(readout={"timing": {"policy": "ignore"}}, sensor_seed=3)
    le = _disc()
    mean = expose(le, cam, cfg, seed=1, exposure_time=1e-3, keep_mean_charge=True).mean_charge
    # the readout (modes, windows, thresholds) and the temporal seed may differ; the sensor
    # (the fixed pattern: here detector.sensor_seed, else the seed) may not
    expose(le, cam, cfg.model_copy(update={"readout": cfg.readout.model_copy(
        update={"modes": ("windows",)})}), seed=2, exposure_time=1e-3, windows=[(0, 0, 4, 4)],
        mean_charge=mean)
    others = [
        dict(radiance=le.copy()),                       # another radiance object
        dict(exposure_time=2e-3),
        dict(config=DetectorConfig(readout={"timing": {"policy": "ignore"}}, sensor_seed=3,
                                   charge={"prnu": {"sigma_fraction": 0.03}})),
        dict(config=cfg.model_copy(update={"sensor_seed": 5})),
    ]
    for change in others:
        kw = dict(radiance=le, exposure_time=1e-3, config=cfg) | change
        with pytest.raises(ConfigError, match="mean_charge"):
            expose(kw["radiance"], cam, kw["config"], seed=2,
                   exposure_time=kw["exposure_time"], mean_charge=mean)
