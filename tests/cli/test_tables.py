"""CLI tables in a pipe never cut a cell; summary values carry their unit with few digits."""

from __future__ import annotations

import typer
from typer.testing import CliRunner

from starnav.cli._output import format_quantity, print_table


def test_plain_table_in_a_pipe_keeps_every_label_whole():
    labels = ["exposure_time_s=1.5e-05, thresholds_dn=[200]",
              "exposure_time_s=1.5e-05, thresholds_dn=[2048]"]
    app = typer.Typer()

    @app.command()
    def show() -> None:
        print_table("sweep: medians over runs", ["point", "scenario", "limb bias [px]"],
                    [[str(k), lab, "+0.12"] for k, lab in enumerate(labels)])

    res = CliRunner().invoke(app, [], env={"COLUMNS": "50"})
    assert res.exit_code == 0
    for lab in labels:   # longer than the 50 columns, whole, on one line
        assert any(lab in line for line in res.output.splitlines())
    assert "…" not in res.output


def test_format_quantity_units_and_digits():
    assert format_quantity("7.7 ms: limb bias [px]", 0.875992) == "+0.876 px"
    assert format_quantity("7.7 ms: final position error [% range]", 0.0123456) == \
        "0.0123 % of range"
    assert format_quantity("7.7 ms: final position error [km]", 12.3456) == "12.3 km"
    assert format_quantity("elapsed_s", 81.23456) == "81.2 s"
    assert format_quantity("dataset_frames_per_s", 0.41234) == "0.412 frames/s"
    assert format_quantity("frames", 25) == "25"
    assert format_quantity("report", "out/demo/report.md") == "out/demo/report.md"
