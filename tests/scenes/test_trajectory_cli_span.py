"""``starnav trajectory``: the summary's span is the OEM's (first to last epoch), in the time
unit of :mod:`starnav.timeaxis` (a 0.05 d arc is "1.1 h", never "0.1 d")."""

from __future__ import annotations

from typer.testing import CliRunner

from starnav.timeaxis import elapsed_axis, format_duration, time_unit


def test_time_unit_rule():
    assert time_unit(0.05 * 86400) == ("h", 3600.0)
    assert time_unit(1.99 * 86400) == ("h", 3600.0)
    assert time_unit(2.0 * 86400) == ("d", 86400.0)
    t, label = elapsed_axis([100.0, 1900.0, 3700.0])
    assert list(t) == [0.0, 0.5, 1.0] and label.endswith("[h]")
    assert format_duration(0.05 * 86400) == "1.2 h"


def test_summary_end_is_the_oems_last_epoch(tmp_path):
    from starnav.cli.main import app

    oem = tmp_path / "t.oem"
    res = CliRunner().invoke(app, ["trajectory", "--out", str(oem), "--set",
                                   "trajectory.duration_days=0.05", "--set",
                                   "trajectory.cadence_s=1000"], env={"COLUMNS": "50"})
    assert res.exit_code == 0, res.output
    data = [ln.split()[0] for ln in oem.read_text().splitlines()
            if ln[:4].isdigit() and len(ln.split()) == 7]
    first, last = data[0][:19], data[-1][:19]
    # 0.05 d = 4320 s at 1000 s: epochs 0..4000 s, the OEM ends at 01:06:40
    assert last.endswith("T01:06:40")
    text = " ".join(res.output.split())
    assert f"{first} TDB .. {last} TDB (1.1 h)" in text
    assert (tmp_path / "t.png").stat().st_size > 10_000
