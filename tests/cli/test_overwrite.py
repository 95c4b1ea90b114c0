"""The one overwrite rule of every command that writes (``starnav.cli._output.check_output``):
an existing file or a non-empty directory is refused unless ``--overwrite`` (``--resume`` for a
dataset), and no command writes into one of its inputs, even with ``--overwrite``. Each line:
the command, exit 2, one ``error:`` line naming the path, and nothing written or changed
anywhere (the whole tree compared before and after)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from tests.dataset.conftest import small_dataset, tree_bytes, write_small_yaml  # noqa: F401

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")

#: name -> (arguments, the path the error names, a word the error must hold). In the
#: arguments: SC a small scenario, EXR a radiance image, DS a dataset, FOREIGN a directory
#: holding another command's report.md, FILE an existing file, T the test's directory.
CASES = {
    "init over a file": (["init", "FILE"], "FILE", "--overwrite"),
    "render into a foreign dir": (["render", "SC", "--out", "FOREIGN"], "FOREIGN", "not empty"),
    "render into its input": (["render", "SC", "--out", "SC", "--overwrite"], "SC", "input"),
    "demo into a foreign dir": (["demo", "--out", "FOREIGN"], "FOREIGN", "not empty"),
    "trajectory over its scenario": (["trajectory", "SC", "--out", "SC", "--overwrite"],
                                     "SC", "input"),
    "trajectory plot over its scenario": (["trajectory", "SC", "--out", "T/t.oem", "--plot",
                                           "SC", "--overwrite"], "SC", "input"),
    "trajectory over a file": (["trajectory", "SC", "--out", "FILE"], "FILE", "--overwrite"),
    "trajectory plot over a file": (["trajectory", "SC", "--out", "T/t.oem", "--plot", "FILE"],
                                    "FILE", "--overwrite"),
    "show over a file": (["show", "SC", "--out", "FILE"], "FILE", "--overwrite"),
    "show over its scenario": (["show", "SC", "--out", "SC", "--overwrite"], "SC", "input"),
    "expose into a foreign dir": (["expose", "EXR", "--out", "FOREIGN"], "FOREIGN",
                                  "not empty"),
    "expose onto its input": (["expose", "EXR", "--out", "EXR", "--overwrite"], "EXR",
                              "input"),
    "navigate into its dataset": (["navigate", "DS", "--out", "DS", "--overwrite"], "DS",
                                  "input"),
    "navigate into a frame": (["navigate", "DS", "--out", "DS/frames/000001", "--overwrite"],
                              "DS/frames/000001", "inside the input"),
    "navigate into a foreign dir": (["navigate", "DS", "--out", "FOREIGN"], "FOREIGN",
                                    "not empty"),
    "sweep into a foreign dir": (["sweep", "SC", "--out", "FOREIGN"], "FOREIGN", "not empty"),
    "dataset into a foreign dir": (["dataset", "SC", "--out", "FOREIGN"], "FOREIGN",
                                   "--resume"),
    "dataset into another dataset": (["dataset", "SC", "--out", "DS/frames", "--resume"],
                                     "DS/frames", "not a starnav dataset"),
    "real amie into a foreign dir": (["real", "amie", "--out", "FOREIGN"], "FOREIGN",
                                     "not empty"),
    "dem mesh over a file": (["dem", "mesh", "SC", "--out", "T/m.ply"], "T/m.ply",
                             "--overwrite"),
    "dem mesh to an unknown type": (["dem", "mesh", "SC", "--out", "T/mesh.xyz"], "T/mesh.xyz",
                                    ".ply"),
    "hil check into a foreign dir": (["hil", "check", "default", "--out", "FOREIGN"],
                                     "FOREIGN", "not empty"),
    "hil geometric into a foreign dir": (["hil", "geometric", "default", "--out", "FOREIGN"],
                                         "FOREIGN", "not empty"),
    "hil radiometric into a foreign dir": (["hil", "radiometric", "default", "--out",
                                            "FOREIGN"], "FOREIGN", "not empty"),
    "hil stimulate into its input": (["hil", "stimulate", "default", "T", "--out", "FOREIGN",
                                      "--overwrite"], "FOREIGN", "inside the input"),
}


@pytest.fixture(scope="module")
def app():
    from starnav.cli.main import app as main_app

    return main_app


def _place(tmp: Path, ds: Path) -> dict[str, str]:
    from starnav.radiance import RadianceImage, write_exr

    sc = write_small_yaml(tmp / "sc.yaml", frames=2)
    exr = write_exr(RadianceImage(L=np.ones((16, 16), np.float32),
                                  Le=np.ones((16, 16), np.float32)), tmp / "in.exr")
    foreign = tmp / "sweep"
    foreign.mkdir()
    (foreign / "report.md").write_text("a sweep's report")
    (tmp / "afile").write_text("the user's file")
    (tmp / "m.ply").write_text("a mesh")
    return {"SC": str(sc), "EXR": str(exr), "DS": str(ds), "FOREIGN": str(foreign),
            "FILE": str(tmp / "afile"), "T": str(tmp)}


def _sub(arg: str, names: dict[str, str]) -> str:
    head, _, rest = arg.partition("/")
    return names[head] + (f"/{rest}" if rest else "") if head in names else arg


@pytest.mark.parametrize("case", list(CASES))
def test_every_writing_command_follows_the_overwrite_rule(app, tmp_path, small_dataset,  # noqa: F811
                                                          case):
    args, named, word = CASES[case]
    names = _place(tmp_path, small_dataset)
    before = tree_bytes(tmp_path), tree_bytes(small_dataset)
    r = CliRunner().invoke(app, [_sub(a, names) for a in args], env={"COLUMNS": "50"})
    assert r.exit_code == 2, (r.exit_code, r.output, repr(r.exception))
    assert "Traceback" not in r.output
    line = next(ln for ln in r.output.splitlines() if ln.startswith("error:"))
    assert _sub(named, names) in line and word in line, line
    assert (tree_bytes(tmp_path), tree_bytes(small_dataset)) == before  # nothing written
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "in.exr", "m.ply", "sc.yaml",
                                                          "sweep"]


def test_overwrite_allows_a_file_and_a_foreign_directory(app, tmp_path):
    """The same commands run with ``--overwrite``: the file is replaced, the directory's own
    files left alone."""
    sc = write_small_yaml(tmp_path / "sc.yaml", frames=1)
    f = tmp_path / "s.yaml"
    f.write_text("old")
    r = CliRunner().invoke(app, ["init", str(f), "--overwrite"])
    assert r.exit_code == 0, r.output
    assert f.read_text().startswith("#")
    foreign = tmp_path / "sweep"
    foreign.mkdir()
    (foreign / "report.md").write_text("a sweep's report")
    r = CliRunner().invoke(app, ["render", str(sc), "--out", str(foreign), "--overwrite"])
    assert r.exit_code == 0, r.output
    assert (foreign / "report.md").read_text() == "a sweep's report"
    assert (foreign / "frame_000000.exr").is_file()


def test_demo_continues_its_own_earlier_run_and_refuses_anything_else(tmp_path):
    """``starnav demo`` re-run into its output continues it (the dataset is resumed); a
    directory holding anything besides a demo's outputs is foreign."""
    from starnav.cli._output import check_output
    from starnav.cli.main import _is_demo_output
    from starnav.errors import DataFileError

    demo = tmp_path / "demo"
    (demo / "dataset").mkdir(parents=True)
    (demo / "dataset" / "manifest.json").write_text("{}")
    (demo / "report.md").write_text("# demo")
    check_output(demo, directory=True, ours=_is_demo_output)   # its own: accepted
    (demo / "notes.txt").write_text("the user's")
    with pytest.raises(DataFileError, match="not empty"):
        check_output(demo, directory=True, ours=_is_demo_output)
