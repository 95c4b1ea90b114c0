"""A fly-by dataset (issue 16): ``starnav dataset FLYBY.yaml --out DS`` stores the radiance and
the truth of every frame, ``starnav navigate DS`` runs the fly-by closed loop on them.

Tiny fly-by of the default suite (as tests/navigation/test_flyby_sweep_rendered.py): Itokawa
at 128 x 128 px, 15 mm, 2 spp, 3 frames 0.2 s apart about CA 5 km at 0.5 km/s, seed 3.

The central check is a seeded regression of exact equality: the closed loop on the frames
read back from the dataset (float32 EXR, geometry from ``truth.json``) gives the same
metrics, run for run, as ``navigate FLYBY.yaml`` rendering the same scenario in memory.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")

from starnav.batch.flyby import flyby_closed_loop
from starnav.cli.main import app
from starnav.config import scenario_to_dict
from starnav.dataset import open as open_dataset
from starnav.dataset import read_manifest
from starnav.dataset.flyby import read_flyby
from starnav.errors import DataFileError
from starnav.simulate import Simulator
from starnav.simulate.flyby import KEPT_AOVS, render_flyby
from tests.flyby_scenarios import tiny_flyby

ENV = {"COLUMNS": "50"}
#: metrics.json keys that are wall times or memory (not results of the closed loop).
MACHINE_KEYS = ("timing_s_per_frame", "tracker_budget")




def invoke(*args: str):
    return CliRunner().invoke(app, list(args), env=ENV)


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    root = tmp_path_factory.mktemp("fbds")
    sc = root / "fb.yaml"
    sc.write_text(yaml.safe_dump(scenario_to_dict(tiny_flyby())))
    ds = root / "ds"
    res = invoke("dataset", str(sc), "--out", str(ds))
    assert res.exit_code == 0, res.output
    return root, sc, ds, res.output


def test_the_dataset_is_marked_fly_by_and_holds_radiance_and_truth_only(made):
    _, _, ds, output = made
    assert "INFEASIBLE" not in output and "fly-by" in output
    man = read_manifest(ds)
    assert man["target_kind"] == "flyby" and man["complete"]
    assert man["exposures"] == [] and man["options"]["windows"] == "closed-loop"
    sim = Simulator(tiny_flyby())
    assert man["flyby"]["epoch_ca_tdb_s"] == sim.scene.flyby.epoch_ca
    assert len(man["frames"]) == 3
    for e in man["frames"]:
        assert sorted(e["files"]) == ["files.json", "radiance.exr", "radiance_quicklook.png",
                                      "truth.json"]
        truth = json.loads((ds / e["directory"] / "truth.json").read_text())
        rel = sim.scene.relative_states[e["index"]]
        np.testing.assert_array_equal(truth["flyby"]["relative_position_m"], rel[:3])
        np.testing.assert_array_equal(truth["flyby"]["relative_velocity_m_s"], rel[3:])


def test_frames_read_back_are_the_renders(made):
    """float32 EXR and JSON floats round-trip exactly: the stored frames are the renders,
    AOVs (hit mask, body-fixed coordinates: the closed loop's, ``KEPT_AOVS``) included."""
    _, _, ds, _ = made
    sim, back = read_flyby(ds)
    renders, _ = render_flyby(Simulator(tiny_flyby()))
    for (g0, i0), (g1, i1) in zip(renders, back, strict=True):
        assert g1.index == g0.index and g1.epoch_tdb == g0.epoch_tdb
        np.testing.assert_array_equal(g1.camera_position, g0.camera_position)
        np.testing.assert_array_equal(g1.R_cam_to_inertial, g0.R_cam_to_inertial)
        # the dataset stores every channel; the loop keeps those it reads
        assert set(i0.aovs) == set(KEPT_AOVS) and set(i0.aovs) < set(i1.aovs)
        np.testing.assert_array_equal(i1.L, i0.L)
        np.testing.assert_array_equal(i1.Le, i0.Le)
        for k in i0.aovs:
            np.testing.assert_array_equal(i1.aovs[k], i0.aovs[k])


def test_the_dataset_verifies(made):
    _, _, ds, _ = made
    res = invoke("dataset", "verify", str(ds))
    assert res.exit_code == 0, res.output
    assert "complete, 3 of 3 frames, 12 files verified" in " ".join(res.output.split())


def test_navigate_dataset_equals_navigate_scenario(made):
    """Seeded regression (exact): ``navigate DS --runs 2`` = ``navigate FLYBY.yaml --runs 2``
    (run 0's metrics and the Monte Carlo summary), the machine's timings aside."""
    root, sc, ds, _ = made
    a, b = root / "nav_ds", root / "nav_yaml"
    ra = invoke("navigate", str(ds), "--out", str(a), "--runs", "2", "--no-plots")
    assert ra.exit_code == 0, ra.output
    rb = invoke("navigate", str(sc), "--out", str(b), "--runs", "2", "--no-plots")
    assert rb.exit_code == 0, rb.output
    ma = json.loads((a / "metrics.json").read_text())
    mb = json.loads((b / "metrics.json").read_text())
    assert ma["monte_carlo"]["runs"] == 2
    assert np.isfinite(ma["ca_position_error_m"]) and ma["ca_range_m"] > 4e3
    assert ma["timing_s_per_frame"]["render"] is None     # not rendered: read back
    assert isinstance(mb["timing_s_per_frame"]["render"], float)
    for k in MACHINE_KEYS:
        ma.pop(k), mb.pop(k)
    assert ma == mb
    assert ra.output.splitlines()[:2] == rb.output.splitlines()[:2]
    # another seed is another run: the equality above is not that of a constant
    rc = invoke("navigate", str(ds), "--out", str(root / "nav_seed"), "--runs", "1",
                "--no-plots", "--seed", "4")
    assert rc.exit_code == 0, rc.output
    mc = json.loads((root / "nav_seed" / "metrics.json").read_text())
    assert mc["ca_position_error_m"] != ma["ca_position_error_m"]


def test_limb_commands_on_a_fly_by_dataset_are_refused(made):
    root, _, ds, _ = made
    res = invoke("navigate", str(ds), "--out", str(root / "x"), "--exposure", "30us")
    assert res.exit_code == 2 and len(res.output.strip().splitlines()) == 1
    assert res.output.startswith("error:") and "--exposure" in res.output
    res = invoke("navigate", str(ds), "--out", str(root / "x"), "--set", "detector.gain=2")
    assert res.exit_code == 2 and len(res.output.strip().splitlines()) == 1
    assert "detector.gain=2" in res.output
    assert not (root / "x").exists()
    with pytest.raises(DataFileError, match="fly-by dataset"):
        open_dataset(ds)


def test_limb_options_of_dataset_are_refused_for_a_fly_by_before_writing(made):
    root, sc, _, _ = made
    for extra in (["--exposures", "7.7ms"], ["--windows", "same"], ["--no-radiance"]):
        out = root / "refused"
        res = invoke("dataset", str(sc), "--out", str(out), *extra)
        assert res.exit_code == 2, (extra, res.output)
        assert len(res.output.strip().splitlines()) == 1 and "fly-by" in res.output
        assert not out.exists()


def test_navigate_dataset_renders_nothing(made, monkeypatch):
    """The closed loop runs on the stored frames: with the renderer disabled it still runs
    and gives the metrics of the scenario's own renders."""
    from starnav.batch.flyby import navigate_flyby_dataset

    root, _, ds, _ = made
    ref = flyby_closed_loop(Simulator(tiny_flyby()), 1).runs[0].metrics

    def no_render(self, index):
        raise AssertionError(f"frame {index} rendered")

    monkeypatch.setattr(Simulator, "render", no_render)
    m = navigate_flyby_dataset(ds, root / "nav_lib", 1, plots=False)
    assert m["ca_position_error_m"] == ref.ca_position_error_m
    assert m["feature_error_rms_px"] == ref.feature_error_rms_px
