"""``starnav init``: every preset writes a commented scenario that loads back to itself."""

from __future__ import annotations

import pytest
import yaml
from typer.testing import CliRunner

from starnav.cli.main import INIT_PRESETS, app
from starnav.config import Scenario, load_scenario, scenario_from_dict
from tests.test_config_base import _check_comments


@pytest.mark.parametrize("preset", list(INIT_PRESETS))
def test_init_writes_a_commented_scenario_that_loads_back_exactly(tmp_path, preset):
    out = tmp_path / f"{preset}.yaml"
    res = CliRunner().invoke(app, ["init", str(out), "--preset", preset], env={"COLUMNS": "50"})
    assert res.exit_code == 0, res.output
    header, data = INIT_PRESETS.get(preset)()
    text = out.read_text()
    assert text.startswith(header)
    assert yaml.safe_load(text) == data                  # the same mapping, key for key
    assert load_scenario(out) == scenario_from_dict(data)  # the same Scenario
    checked: list[str] = []
    _check_comments(yaml.compose(text), Scenario, text.splitlines(), "", checked)
    assert {c.split(" ")[0] for c in checked} >= {"seed", "detector.adc.bits", "navigation.runs"}
    body = text.removeprefix(header).splitlines()
    assert max(len(line) for line in body) <= 100  # wrapped comments (the header: the preset)


def test_the_default_preset_shows_the_unused_trajectory_section(tmp_path):
    out = tmp_path / "s.yaml"
    assert CliRunner().invoke(app, ["init", str(out)]).exit_code == 0
    text = out.read_text()
    assert "\ntrajectory: null\n# trajectory:  (example: TrajectoryConfig at its defaults)\n" \
        in text
    # uncommenting the example gives a valid scenario with that trajectory
    lines = text.split("\ntrajectory: null\n")[1].splitlines()[1:]
    block = [ln[2:] for ln in lines[:next(i for i, ln in enumerate(lines) if ln[:1] != "#")]]
    sc = scenario_from_dict({"trajectory": yaml.safe_load("\n".join(block))})
    assert sc.trajectory is not None and sc.trajectory.source == "halo"
