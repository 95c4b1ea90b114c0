"""One answer to "is this a fly-by?" (``simulate.flyby.is_flyby_scenario``) for every command:
the trajectory is a fly-by. Such a scenario takes the fly-by paths (closed loop, fly-by sweep,
fly-by dataset), where a body the closed loop cannot navigate is refused before any work; a
small body on any other trajectory is a limb scenario. Nothing is rendered here."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from starnav.batch.presets import flyby_scenario
from starnav.cli.main import app
from starnav.config import scenario_from_dict, scenario_to_dict
from starnav.dataset import generate
from starnav.errors import ConfigError
from starnav.simulate.flyby import check_flyby_scenario, is_flyby_scenario


def _ellipsoid_flyby():
    d = flyby_scenario()
    d["target"] = {"kind": "ellipsoid"}
    return scenario_from_dict(d)


def _small_body_static():
    return scenario_from_dict({"target": {"kind": "shape_model", "model": "itokawa"},
                               "geometry": {"range_km": 5.0}})


def test_the_trajectory_decides():
    assert is_flyby_scenario(scenario_from_dict(flyby_scenario()))
    assert is_flyby_scenario(_ellipsoid_flyby())  # a fly-by the closed loop refuses ...
    with pytest.raises(ConfigError, match="target.kind.*shape_model"):
        check_flyby_scenario(_ellipsoid_flyby())  # ... with one clear error
    assert not is_flyby_scenario(_small_body_static())  # a small body's limb scenario
    assert not is_flyby_scenario(scenario_from_dict({}))  # the Moon


def test_a_flyby_the_closed_loop_cannot_take_is_refused_before_work(tmp_path):
    """``dataset`` and ``sweep`` of an ellipsoid on a fly-by: exit 2 naming target.kind,
    nothing written (the limb sweep used to take it and fail inside a render task)."""
    with pytest.raises(ConfigError, match="target.kind"):
        generate(_ellipsoid_flyby(), tmp_path / "ds")
    assert not (tmp_path / "ds").exists()
    import yaml

    sc = tmp_path / "sc.yaml"
    sc.write_text(yaml.safe_dump(scenario_to_dict(_ellipsoid_flyby())))
    res = CliRunner().invoke(app, ["sweep", str(sc), "--grid", "v_inf_km_s=0.5", "--runs", "1",
                                   "--workers", "0", "--out", str(tmp_path / "sw")])
    assert res.exit_code == 2, res.output
    assert "target.kind" in res.output and not (tmp_path / "sw").exists()
