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


def test_real_limb_is_larger_than_the_nominal_camera_predicts_not_the_chain(results):
    """With the instrument kernel's focal length (154.7 mm) the chain's range from the real
    limb is 1.2 % short at 105 deg, r ~ 98 px (measured -1.23 %), while on the simulated frame
    it is right (+0.14 %). A measure that involves no navigation chain, the circle through the
    half-maximum edges, shows the same on the real image (+1.45 %) and not on the simulated
    one (+0.04 %): the real image's scale differs from the nominal camera's."""
    r = results["040819_00208"]
    assert -1.6 < r.nav_range_error_pct < -0.9, r
    assert abs(r.nav_range_error_sim_pct) < 0.5, r
    assert 1.009 < r.edge_radius_ratio_real < 1.02, r
    assert abs(r.edge_radius_ratio_sim - 1.0) < 0.005, r


def test_navigation_range_within_1_percent_with_the_focal_length_of_other_epochs():
    """Issue 12: range from the real limb within 1 % of the label's (goal 0.3 %). The chain
    runs on all five real Moon frames (no rendering); each frame is scored with a focal length
    calibrated on the *other* days only (leave-one-epoch-out: the 041111 pair is one epoch).
    Measured: +0.06, +0.18, -0.51, +0.25, +0.28 %; the factor 1.013-1.015 on every split (one
    focal length serves all epochs, ~156.8 mm)."""
    from starnav.reference.amie.frame import AMIE_FRAMES
    from starnav.reference.amie.validate import focal_scale_cross_validation, real_limb_fix

    fixes = [real_limb_fix(packaged_frame(n)) for n in AMIE_FRAMES if "040326" not in str(n)]
    assert len(fixes) == 5
    # nominal focal length: every frame short by 1.1-1.8 %
    assert all(-1.9 < f.range_error_pct < -1.0 for f in fixes), [f.range_error_pct for f in fixes]
    cv = focal_scale_cross_validation(fixes)
    errors = [cv[f.name]["error_pct"] for f in fixes]
    assert all(abs(e) < 1.0 for e in errors), errors
    assert sum(abs(e) < 0.3 for e in errors) >= 4, errors
    scales = [cv[f.name]["scale"] for f in fixes]
    assert max(scales) - min(scales) < 0.005, scales


def test_the_phase_law_of_the_calibrated_moon_holds_on_real_frames(results):
    """The relative brightness of the two frames (phases 7.5 and 105 deg, 671 000 and 198 000
    km, 5 and 30 ms) is the real Moon's within 5 %: the calibrated photometry's phase
    dependence is right, whatever the AMIE's absolute efficiency."""
    a, b = results["041028_00269"], results["040819_00208"]
    assert b.signal_ratio / a.signal_ratio == pytest.approx(1.0, abs=0.05)
    # the per-pixel pattern (maria, craters, terminator) correlates with the real one
    assert a.pixel_correlation > 0.95 and b.pixel_correlation > 0.95


def test_absolute_signal_within_10_percent_with_the_qe_measured_on_vega(results):
    """Issue 12: disc-integrated signal simulated / real within 10 % (goal 5 %), with the
    calibrated Moon and the AMIE's QE measured on Vega (frame 040326, not a Moon frame; no
    per-frame tuning). Measured at 16 spp: 0.910 (7.5 deg, in the Earth's penumbra; 0.944
    without the shadow) and 0.918 (105 deg)."""
    for r in results.values():
        assert abs(r.signal_ratio - 1.0) < 0.10, r


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


@pytest.mark.slow
def test_all_five_moon_frames_against_the_criteria(tmp_path):
    """The whole validation at 16 spp (~30 s): every frame's limb within 1 px rms, the range
    within 1 % with the focal length of the other epochs, the four REGULAR frames' signal
    within 10 %, and the one outside (040504, a CALIBRATION-sequence frame) explained in the
    report."""
    from starnav.reference.amie.validate import run_amie_validation

    out = run_amie_validation(None, tmp_path / "amie")
    frames = out["frames"]
    assert len(frames) == 5
    for r in frames:
        assert r.limb_diff_rms_px < 1.0, r
        assert abs(r.nav_range_error_flight_cal_pct) < 1.0, r
        if r.observation_type == "REGULAR":
            assert abs(r.signal_ratio - 1.0) < 0.10, r
    odd = [r for r in frames if r.observation_type != "REGULAR"]
    assert [r.name for r in odd] == ["AMI_EE3_040504_00013_00020"]
    report = (tmp_path / "amie" / "report.md").read_text()
    assert "CALIBRATION sequence" in report and "2.0" in report
    assert abs(out["linearity"]["relative_error"]) < 0.02


# --------------------------------------------------------------------------- a run of many
IMAGE_OFFSET = 36865 - 1         # ^IMAGE = 36865 <BYTES> in every packaged label


def _moon_moved_right(name: str, shift_px: int, out):
    """A packaged frame with its image moved ``shift_px`` columns to the right, the columns
    that come in filled with the frame's own dark sky (columns 300-511, cyclically), the label
    unchanged: the Moon is cut by the right edge and the label's pointing is off by the shift
    (``shift_px`` x 90 urad), the case of a frame whose pointing missed the Moon."""
    import numpy as np

    blob = packaged_frame(name).read_bytes()
    stored = np.frombuffer(blob, "<u2", count=512 * 512, offset=IMAGE_OFFSET).reshape(512, 512)
    new = np.empty_like(stored)
    new[:, shift_px:] = stored[:, :512 - shift_px]
    new[:, :shift_px] = stored[:, 300 + np.arange(shift_px) % 212]
    new[511, 510:] = stored[511, 510:]                  # the marker pixels stay
    out.write_bytes(blob[:IMAGE_OFFSET] + new.astype("<u2").tobytes()
                    + blob[IMAGE_OFFSET + new.nbytes:])
    return out


def test_one_frame_never_aborts_a_run_of_many(tmp_path):
    """Three frames in one run: 041028 (compared, fix, in the Earth's penumbra), 040819 at
    phase 105 deg with the chain's thin-crescent limit set to 100 deg (no fix: still compared
    on its limb points),
    and 041028 moved 270 px right (the disc's centre 14 px beyond the edge, a sliver in the
    image, the label pointing 1.4 deg off): cannot be compared, with the reason and no
    numbers. The run completes and report.md and results.json say what happened to each."""
    from starnav.reference.amie.validate import AmieOptions, run_amie_validation

    cut = _moon_moved_right("041028_00269", 270, tmp_path / "AMI_CUT.IMG")
    paths = [packaged_frame("041028_00269"), packaged_frame("040819_00208"), cut]
    out = run_amie_validation(paths, tmp_path / "o", AmieOptions(spp=1, max_phase_deg=100.0))
    ok, crescent, edge = out["frames"]
    assert (ok.comparison, ok.navigation) == ("compared", "fix")
    assert math.isfinite(ok.nav_range_error_pct) and ok.limb_diff_rms_px < 1.0
    # 041028 is in the outer penumbra of the 2004-10-28 eclipse (27 min before the last
    # contact): the report says so
    assert 0.95 < ok.sunlit_fraction < 0.99
    assert any("Earth's shadow" in n for n in ok.notes)
    assert (crescent.comparison, crescent.navigation) == ("compared", "no fix")
    assert "thin-crescent" in crescent.navigation_reason
    assert crescent.limb_diff_rms_px < 1.0 and abs(crescent.signal_ratio - 1.0) < 0.15
    assert math.isnan(crescent.nav_range_error_pct)
    assert edge.comparison == "cannot be compared" and "limb" in edge.comparison_reason
    assert math.isnan(edge.signal_ratio) and math.isnan(edge.limb_diff_rms_px)

    doc = json.loads((tmp_path / "o" / "results.json").read_text())
    by_name = {f["name"]: f for f in doc["frames"]}
    assert by_name["AMI_CUT"]["comparison"] == "cannot be compared"
    assert by_name["AMI_CUT"]["signal_ratio"] is None          # no numbers, valid JSON
    assert by_name["AMI_EE3_040819_00208_00030"]["navigation"] == "no fix"
    report = (tmp_path / "o" / "report.md").read_text()
    assert "**AMI_CUT**" in report and "cannot be compared" in report
    assert "| AMI_CUT |" not in report                         # no row of numbers
    assert not (tmp_path / "o" / "figures" / "AMI_CUT.png").exists()


def test_a_single_frame_gets_a_calibrated_range(results):
    """One frame alone (no other epoch: the leave-one-epoch-out focal length is NaN) gets its
    range with the shipped in-flight focal length, within 2 x its stated 1-sigma of the
    label's (measured: 040819 +0.14 %, 041028 -0.38 %; nominal -1.23 %, -1.75 %)."""
    for r in results.values():
        assert math.isnan(r.focal_scale_other_epochs)
        assert math.isfinite(r.nav_range_calibrated_km)
        assert abs(r.nav_range_error_calibrated_pct) <= 2.0 * r.nav_range_sigma_calibrated_pct, r
        assert r.nav_range_error_pct < -1.0 < r.nav_range_error_calibrated_pct


def _circle_limb(centre, radius_px, from_deg, to_deg, n=300):
    import numpy as np

    from starnav.reference.amie.validate import LimbSolution

    t = np.radians(np.linspace(from_deg, to_deg, n))
    uv = np.c_[centre[0] + radius_px * np.cos(t), centre[1] + radius_px * np.sin(t)]
    return LimbSolution(uv, np.full(n, 0.3), None, math.nan, np.asarray(centre, float),
                        radius_px, "fix-failed", "synthetic", uv)


@pytest.mark.parametrize("case", ["inside", "mostly outside", "sliver", "not a circle"])
def test_when_a_frame_can_be_compared(case):
    """The comparability rule on synthetic limbs (no image): a disc inside the field passes;
    a disc whose centre lies 18 px beyond the right edge (31 % of it inside) is 'mostly
    outside' although 140 deg of its limb are visible; a quarter of a limb around a centre
    beyond the corner, most of it outside the image, is too little limb; points on a circle
    twice the label's radius do not converge."""
    import numpy as np

    from starnav.camera import Camera
    from starnav.reference.amie.validate import AmieOptions, limb_in_valid_area

    cam = Camera.preset("amie")
    valid = np.ones((512, 512), bool)
    rho = math.atan(60.0 / cam.fx)                   # the label's radius: 60 px
    limb = {"inside": _circle_limb((256, 256), 60.0, 0, 180),
            "mostly outside": _circle_limb((530, 256), 60.0, 0, 360),
            "sliver": _circle_limb((540, 540), 60.0, 180, 270, n=40),
            "not a circle": _circle_limb((256, 256), 120.0, 0, 180)}[case]
    direction, reason = limb_in_valid_area(limb, valid, cam, rho, AmieOptions())
    if case == "inside":
        assert reason == ""
        np.testing.assert_allclose(cam.project(direction[None, :])[0], (256, 256), atol=0.5)
    else:
        key = {"mostly outside": "mostly outside", "sliver": "too little limb",
               "not a circle": "did not converge"}[case]
        assert key in reason, reason
