"""``starnav navigate`` reads a dataset only as its manifest describes it: a file deleted,
edited, truncated or added after the dataset was made, or a truth.json with a key missing or
malformed (its hash made to match, as a hand-edited dataset would), is refused with one
``error:`` line naming the file (and the key), exit 2, and nothing written."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from starnav.dataset import format as F

from .conftest import small_dataset  # noqa: F401

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")

E0 = "exposure_0.015ms"


def _relist(ds: Path, frame: str, rel: str) -> None:
    """Make the manifest agree with the file as it now is (a hand-edited dataset)."""
    man = json.loads((ds / F.MANIFEST).read_text())
    p = ds / F.FRAMES_DIR / frame / rel
    for e in man["frames"]:
        if e["directory"].endswith(frame):
            e["files"][rel] = {"bytes": p.stat().st_size, "sha256": F.sha256_file(p)}
    F.write_json(ds / F.MANIFEST, man)


def _edit_truth(ds: Path, change) -> None:
    p = ds / F.FRAMES_DIR / "000001" / F.TRUTH
    d = json.loads(p.read_text())
    change(d)
    p.write_text(json.dumps(d))
    _relist(ds, "000001", F.TRUTH)


def _delete(rel):
    return lambda ds: (ds / F.FRAMES_DIR / "000001" / rel).unlink()


def _append(rel):
    return lambda ds: (ds / F.FRAMES_DIR / "000001" / rel).write_text(
        (ds / F.FRAMES_DIR / "000001" / rel).read_text().replace("1", "2", 1))


def _truncate(rel):
    def cut(ds):
        p = ds / F.FRAMES_DIR / "000001" / rel
        p.write_bytes(p.read_bytes()[:500])
    return cut


def _add(ds):
    (ds / F.FRAMES_DIR / "000001" / E0 / F.STAR_DN).write_bytes(b"\x89PNG not listed")


#: case -> (damage, what the error names, a word of it).
CASES = {
    "segments deleted": (_delete(f"{E0}/{F.SEGMENTS}"), f"000001/{E0}/{F.SEGMENTS}", "missing"),
    "windows deleted": (_delete(f"{E0}/{F.WINDOWS}"), f"000001/{E0}/{F.WINDOWS}", "missing"),
    "segments edited": (_append(f"{E0}/{F.SEGMENTS}"), f"000001/{E0}/{F.SEGMENTS}", "differs"),
    "dn truncated": (_truncate(f"{E0}/{F.DN}"), f"000001/{E0}/{F.DN}", "differs"),
    "truth deleted": (_delete(F.TRUTH), f"000001/{F.TRUTH}", "missing"),
    "unlisted file": (_add, f"000001/{E0}/{F.STAR_DN}", "not in the dataset's manifest"),
    "truth without a key": (
        lambda ds: _edit_truth(ds, lambda d: d["geometry"].pop("R_cam_to_inertial")),
        f"000001/{F.TRUTH}", "'geometry.R_cam_to_inertial' is missing"),
    "truth with a bad attitude": (
        lambda ds: _edit_truth(ds, lambda d: d["attitude"].update(
            R_cam_to_inertial_measured=[1, 2])),
        f"000001/{F.TRUTH}", "'attitude.R_cam_to_inertial_measured'"),
    "truth without the Sun": (
        lambda ds: _edit_truth(ds, lambda d: d.pop("sun")),
        f"000001/{F.TRUTH}", "'sun.direction_from_moon' is missing"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_navigate_refuses_a_dataset_that_does_not_match_its_manifest(small_dataset,  # noqa: F811
                                                                     tmp_path, case):
    from starnav.cli.main import app

    damage, named, word = CASES[case]
    ds = tmp_path / "ds"
    shutil.copytree(small_dataset, ds)
    damage(ds)
    out = tmp_path / "nav"
    r = CliRunner().invoke(app, ["navigate", str(ds), "--out", str(out), "--no-plots"],
                           env={"COLUMNS": "50"})
    assert r.exit_code == 2, (r.output, repr(r.exception))
    assert "Traceback" not in r.output
    line = next(ln for ln in r.output.splitlines() if ln.startswith("error:"))
    assert named in line and word in line, line
    assert not out.exists() or not any(p.is_file() for p in out.rglob("*"))
