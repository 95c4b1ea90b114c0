"""Config entry points (load_dem / load_albedo) and the ``starnav dem`` commands."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
import typer
import yaml
from _dem_files import write_pds3
from typer.testing import CliRunner

from starnav.dem import load_albedo, load_dem
from starnav.dem.load import as_dem_config, clear_cache
from starnav.dem.schema import AlbedoConfig, DemConfig
from starnav.errors import ConfigError


def _app() -> typer.Typer:
    from starnav.cli.main import app  # the real command line

    return app


def test_defaults_are_the_procedural_moon_without_albedo_map():
    cfg = DemConfig()
    assert cfg.source == "procedural" and cfg.albedo is None
    assert load_albedo(cfg) is None
    small = as_dem_config({"procedural": {"pixels_per_degree": 1.0}})
    g = load_dem(small)
    assert g.shape == (180, 360) and g.source.startswith("procedural")
    assert load_dem(small) is g  # cached


def test_dem_config_rejects_unknown_keys_and_bad_values():
    with pytest.raises(ConfigError, match=r"moon\.dem\.sorce"):
        as_dem_config({"sorce": "x.tif"})
    with pytest.raises(ConfigError, match=r"moon\.dem\.procedural\.pixels_per_degree"):
        as_dem_config({"procedural": {"pixels_per_degree": -1}})
    with pytest.raises(ConfigError, match=r"moon\.dem\.albedo\.decoding"):
        as_dem_config({"albedo": {"decoding": "gamma"}})


def test_load_albedo_procedural_matches_the_dem_world_and_normalises():
    cfg = as_dem_config({"procedural": {"pixels_per_degree": 1.0, "seed": 9},
                         "albedo": {"source": "procedural", "normalize_mean": 0.12}})
    a = load_albedo(cfg)
    assert a.shape == load_dem(cfg).shape
    assert a.mean == pytest.approx(0.12, rel=1e-5)
    w = load_albedo(DemConfig(procedural=cfg.procedural,
                              albedo=AlbedoConfig(quantity="hapke_w")))
    assert w.quantity == "hapke_w"
    np.testing.assert_allclose(w.values, load_albedo(DemConfig(
        procedural=cfg.procedural, albedo=AlbedoConfig())).values)


def test_load_from_file_and_cache_follows_the_file(tmp_path, relief_dn):
    clear_cache()
    lbl = write_pds3(tmp_path, "LDEM_C", relief_dn)
    g1 = load_dem(DemConfig(source=str(lbl)))
    assert load_dem(DemConfig(source=str(lbl))) is g1
    write_pds3(tmp_path, "LDEM_C", relief_dn // 2)  # rewritten: new size/mtime -> reloaded
    import os

    os.utime(tmp_path / "LDEM_C.LBL", ns=(1, 1))
    g2 = load_dem(DemConfig(source=str(lbl)))
    np.testing.assert_allclose(g2.heights, (relief_dn // 2) * 0.5, atol=2e-3)


def test_cli_dem_info(tmp_path, relief_dn):
    lbl = write_pds3(tmp_path, "LDEM_I", relief_dn)
    r = CliRunner().invoke(_app(), ["dem", "info", str(lbl), "--json"])
    assert r.exit_code == 0, r.output
    info = json.loads(r.output)
    assert info["shape"] == [36, 72]
    assert info["pixels_per_degree"] == pytest.approx(0.2)
    assert info["height_max_m"] == pytest.approx(relief_dn.max() * 0.5, abs=2e-3)
    r = CliRunner().invoke(_app(), ["dem", "info", str(lbl)])
    assert r.exit_code == 0 and "36 x 72" in " ".join(r.output.split())
    bad = CliRunner().invoke(_app(), ["dem", "info", str(tmp_path / "missing.LBL")])
    assert bad.exit_code == 2 and "does not exist" in " ".join(bad.output.split())


def test_cli_dem_mesh_writes_the_frame_mesh(tmp_path):
    sc = {"moon": {"shape": "dem", "dem": {"procedural": {"pixels_per_degree": 1.0}}},
          "geometry": {"range_km": 80_000.0}}
    path = tmp_path / "sc.yaml"
    path.write_text(yaml.safe_dump(sc))
    out = tmp_path / "o" / "mesh.ply"
    r = CliRunner().invoke(_app(), ["dem", "mesh", str(path), "--out", str(out)])
    assert r.exit_code == 0, r.output
    m = trimesh.load(out, process=False)
    assert len(m.faces) > 10_000
    r_km = np.linalg.norm(m.vertices, axis=1) / 1e3
    assert 1725 < r_km.min() and r_km.max() < 1750  # body-fixed metres around the Moon
    assert (tmp_path / "o" / "scenario.resolved.yaml").is_file()
    bad = CliRunner().invoke(_app(), ["dem", "mesh", str(path), "--out", str(out),
                                      "--overwrite", "--set", "moon.dem.source=/nonexistent.tif"])
    assert bad.exit_code == 2 and "does not exist" in " ".join(bad.output.split())
