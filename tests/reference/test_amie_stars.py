"""Vega on the real AMIE frame 040326 (200 ms) against the star field of starnav.stars."""

from __future__ import annotations

import pytest

from starnav.reference.amie.stars import vega_check

#: Issue 17: total signal within 20 % (goal 10 %).
TOTAL_TOL = 0.20


@pytest.fixture(scope="module")
def check():
    return vega_check(seed=0)


def test_vega_total_and_peak_against_the_real_frame(check):
    msg = (f"Vega (HIP 91262, V = {check.vega_v_mag:.3f} from Hp): simulated "
           f"{check.sim_total_dn:.1f} DN total, {check.sim_peak_dn:.0f} DN peak; real "
           f"{check.real_total_dn:.1f} DN, {check.real_peak_dn:.1f} DN; total ratio "
           f"{check.total_ratio:.3f} (QE measured on this frame: circular for the QE), "
           f"{check.total_ratio_moon_qe:.3f} with the Moon frames' QE, "
           f"{check.total_ratio_manual_qe:.3f} with the manual's 0.15; peak ratio "
           f"{check.peak_ratio:.3f}")
    print(msg)
    # with the QE measured on this frame the ratio tests only the star radiometry (V from
    # Hp, black body, zero point) against Vega's CALSPEC spectrum in the AMIE band
    assert abs(check.total_ratio - 1.0) < 0.10, msg
    # independent of this frame: the QE the ROLO-calibrated Moon frames imply
    assert abs(check.total_ratio_moon_qe - 1.0) < TOTAL_TOL, msg
    # the manual's lower bound is 30 % short: the honest number, not a pass
    assert check.total_ratio_manual_qe < 0.8, msg
    # peak: the PSF core was fitted on this frame (sigma 0.51 px); the chain's point-source
    # PSF at the same sub-pixel centre gives the peak within 20 %
    assert abs(check.peak_ratio - 1.0) < TOTAL_TOL, msg
    assert check.sim_electrons_e == pytest.approx(check.sim_total_dn * 280.0, rel=0.05)
