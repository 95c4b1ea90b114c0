"""starnav against real SMART-1 AMIE frames (issue 12): the fast guards of the default run.

Two real frames from the package: 041028_00269 (phase 7.5 deg, full disc r ~ 30 px, 5 ms) and
040819_00208 (phase 105 deg, r ~ 98 px, 30 ms, craters at the terminator). Each is rebuilt from
its label, rendered on the default real Moon with the AMIE camera (no per-frame tuning) and
compared; numbers measured on this machine are in docs/real-images.md.
"""

from __future__ import annotations

import json
import math

import pytest
from typer.testing import CliRunner

from starnav.reference.amie.frame import packaged_frame
from starnav.reference.amie.validate import AmieOptions, analyse_frame

FRAMES = ("041028_00269", "040819_00208")


@pytest.fixture(scope="module")
def results():
    return {f: analyse_frame(packaged_frame(f), AmieOptions(spp=4))[0] for f in FRAMES}


@pytest.mark.parametrize("name", FRAMES)
def test_rendered_limb_matches_the_real_limb_within_1_px_rms(results, name):
    """Issue 12: after the attitude refinement, the half-maximum edge of the rendered Moon and
    of the real one, on the same 90 rays along the lit limb, agree within 1 px rms."""
    r = results[name]
    assert r.limb_points >= 45
    assert r.limb_diff_rms_px < 1.0, r
    # the label pointing was good on these frames: the refinement is small (< 0.1 deg)
    assert r.attitude_correction_deg < 0.1


def test_navigation_range_from_the_real_limb(results):
    """Range from the real limb against the label's (issue 12 asks 1 %, goal 0.3 %). Measured
    at 105 deg, r ~ 98 px: -1.23 %, while the same chain on the simulated frame gives
    +0.14 %: the real limb is read 1.2-1.8 % too large on every frame (the real optics' halo;
    docs/real-images.md). This pins the current state: 1 % is not met."""
    r = results["040819_00208"]
    assert abs(r.nav_range_error_pct) < 1.5, r
    assert abs(r.nav_range_error_sim_pct) < 0.5, r


def test_the_phase_law_of_the_calibrated_moon_holds_on_real_frames(results):
    """The relative brightness of the two frames (phases 7.5 and 105 deg, 671 000 and 198 000
    km, 5 and 30 ms) is the real Moon's within 5 %: the calibrated photometry's phase
    dependence is right, whatever the AMIE's absolute efficiency."""
    a, b = results["041028_00269"], results["040819_00208"]
    assert b.signal_ratio / a.signal_ratio == pytest.approx(1.0, abs=0.05)
    # the per-pixel pattern (maria, craters, terminator) correlates with the real one
    assert a.pixel_correlation > 0.95 and b.pixel_correlation > 0.95


def test_absolute_signal_is_the_known_amie_efficiency_gap(results):
    """Documented limitation, pinned: with the AMIE user manual's QE of 0.15 ('> 15 % at 640
    nm', as ABRAM uses it) the simulation collects 0.66 of the real signal on every frame;
    the manual gives a lower bound only. A change of this ratio is a change of the radiometry
    and must be looked at (docs/real-images.md)."""
    for r in results.values():
        assert 0.6 < r.signal_ratio < 0.72, r


def test_cli_writes_report_json_and_figure(tmp_path):
    from starnav.cli.main import app

    out = tmp_path / "amie"
    res = CliRunner().invoke(app, ["real", "amie", str(packaged_frame("041028_00269")),
                                   "--out", str(out), "--spp", "2"])
    assert res.exit_code == 0, res.output
    doc = json.loads((out / "results.json").read_text())
    assert doc["frames"][0]["name"] == "AMI_EE3_041028_00269_00005"
    assert math.isfinite(doc["frames"][0]["signal_ratio"])
    assert (out / "figures" / "AMI_EE3_041028_00269_00005.png").stat().st_size > 10_000
    assert "| AMI_EE3_041028_00269_00005 |" in (out / "report.md").read_text()


def test_cli_refuses_a_truncated_frame_before_any_work(tmp_path):
    from starnav.cli.main import app

    src = packaged_frame("041028_00269").read_bytes()
    bad = tmp_path / "AMI_truncated.IMG"
    bad.write_bytes(src[: len(src) // 2])
    res = CliRunner().invoke(app, ["real", "amie", str(packaged_frame("040819_00208")),
                                   str(bad), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2
    msg = " ".join(res.output.split())
    assert "AMI_truncated.IMG" in msg
    assert not (tmp_path / "o").exists()
