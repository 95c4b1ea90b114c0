"""The result table: documented columns (docs/sweep.md), units in Parquet, exact CSV floats."""

from __future__ import annotations

import csv
import io
import math
import re
from pathlib import Path

from starnav.batch.table import COLUMNS, STAR_COLUMNS, column_names, to_arrow, to_csv, write_table

DOC = Path(__file__).resolve().parents[2] / "docs" / "sweep.md"


def test_every_column_is_documented_with_its_unit():
    text = DOC.read_text()
    rows = {m.group(1): (m.group(2).strip(), m.group(3).strip())
            for m in re.finditer(r"^\| `([a-z0-9_]+)` \| (\w+) \| ([^|]+) \|", text, re.M)}
    for c in COLUMNS + STAR_COLUMNS:
        assert c.name in rows, f"{c.name} missing from docs/sweep.md"
        assert rows[c.name] == (c.kind, c.unit), c.name
    assert set(rows) >= {c.name for c in COLUMNS + STAR_COLUMNS}


def test_units_in_names_match_the_declared_units():
    suffix_unit = {"_m": "m", "_m_s": "m/s", "_px": "px", "_s": "s", "_pct_range": "%",
                   "_pct_speed": "%"}
    for c in COLUMNS + STAR_COLUMNS:
        for suf, unit in sorted(suffix_unit.items(), key=lambda kv: -len(kv[0])):
            if c.name.endswith(suf):
                assert c.unit == unit, c.name
                break


def test_csv_floats_round_trip_and_parquet_carries_units(tmp_path):
    rows = [{"point": 0, "run": 0, "label": "a", "limb_bias_px": 0.1 + 0.2,
             "readout_feasible": False, "final_position_error_m": math.nan,
             "detector.exposure_time_s": 1.5e-5}]
    cols = column_names(["detector.exposure_time_s"])
    assert cols[:4] == ["point", "run", "label", "detector.exposure_time_s"]
    back = next(csv.DictReader(io.StringIO(to_csv(rows, cols))))
    assert float(back["limb_bias_px"]) == 0.1 + 0.2
    assert back["final_position_error_m"] == "nan" and back["readout_feasible"] == "false"
    t = to_arrow(rows, cols)
    f = t.schema.field("limb_bias_px")
    assert f.metadata[b"unit"] == b"px" and b"true limb" in f.metadata[b"description"]
    paths = write_table(rows, cols, tmp_path)
    import pyarrow.parquet as pq

    assert pq.read_table(paths["parquet"]).to_pylist()[0]["limb_bias_px"] == 0.1 + 0.2
