"""Nothing lost, nothing silent (issue 15): a dataset is complete and verified, or says exactly
what is missing; a worker killed mid-frame leaves no temporary behind; files are fsynced before
their rename and their directory after it."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

import starnav.dataset as ds
from starnav.dataset import DatasetOptions, generate, verify
from starnav.dataset import format as F
from starnav.dataset.runner import InProcessRunner
from starnav.errors import DataFileError
from tests.faults import die_once

from .conftest import small_scenario, tree_bytes

OPTS = DatasetOptions(exposures_s=(1.5e-5, 7.7e-3))


def _partial_copy(src: Path, dst: Path, keep: int) -> Path:
    """``src`` as an interrupted run leaves it: ``keep`` frames listed and on disk, the manifest
    incomplete."""
    shutil.copytree(src, dst)
    man = json.loads((dst / F.MANIFEST).read_text())
    for e in man["frames"][keep:]:
        shutil.rmtree(dst / e["directory"])
    man["frames"] = man["frames"][:keep]
    man["frames_done"], man["complete"] = keep, False
    (dst / F.MANIFEST).write_text(F.dumps(man))
    return dst


# --------------------------------------------------------------------------- verify
def test_verify_reports_an_incomplete_dataset_and_leftover_temporaries(small_dataset, tmp_path):
    out = _partial_copy(small_dataset, tmp_path / "part", keep=3)
    problems = verify(out)
    assert problems == ["incomplete: 3 of 4 frames (missing: 3); finish it with "
                        "`starnav dataset SCENARIO --out DIR --resume`"]
    (out / "frames" / ".tmp-000003-x1y2").mkdir()
    problems = verify(out)
    assert len(problems) == 2
    assert "unfinished frame directory frames/.tmp-000003-x1y2" in problems[1]
    assert ds.open(out, allow_incomplete=True).verify() == problems  # the same from a Dataset


def test_verify_lists_the_missing_frames_of_a_complete_manifest(small_dataset, tmp_path):
    out = tmp_path / "c"
    shutil.copytree(small_dataset, out)
    shutil.rmtree(out / "frames" / "000001")
    assert verify(out) == ["frame 1: directory frames/000001 is missing"]


def test_dataset_verify_command(small_dataset, tmp_path):
    from starnav.cli.main import app

    r = CliRunner().invoke(app, ["dataset", "verify", str(small_dataset)],
                           env={"COLUMNS": "50"})
    assert r.exit_code == 0, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and "4 of 4 frames" in lines[0] and "verified" in lines[0]
    out = _partial_copy(small_dataset, tmp_path / "part", keep=1)
    (out / "frames" / "000000" / "truth.json").write_text("{}")
    r = CliRunner().invoke(app, ["dataset", "verify", str(out)], env={"COLUMNS": "50"})
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output
    assert "frame 0: file truth.json differs from the manifest" in r.output
    assert "incomplete: 1 of 4 frames (missing: 1-3)" in r.output
    r = CliRunner().invoke(app, ["dataset", "verify", str(tmp_path / "nope")],
                           env={"COLUMNS": "50"})
    assert r.exit_code == 2 and "nope" in r.output and "Traceback" not in r.output


# --------------------------------------------------------------------------- generate
class _LeftoverRunner(InProcessRunner):
    """Runs frames in this process and, before frame 1 is made, leaves what a worker killed
    while writing frame 1 leaves: a temporary frame directory."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def as_completed(self, handles):
        for h in list(handles):
            if h.args[-1] == 1:
                (self.root / "frames" / ".tmp-000001-dead").mkdir(parents=True)
                (self.root / "frames" / ".tmp-000001-dead" / "truth.json").write_text("{")
            yield from super().as_completed([h])


def test_generate_removes_the_temporaries_of_frames_it_remade(tmp_path):
    out = tmp_path / "ds"
    generate(small_scenario(frames=2), out, options=DatasetOptions(radiance=False),
             runner=_LeftoverRunner(out))
    assert sorted(p.name for p in (out / "frames").iterdir()) == ["000000", "000001"]
    assert json.loads((out / F.MANIFEST).read_text())["complete"] is True
    assert verify(out) == []


class _CorruptingRunner(InProcessRunner):
    """Frames land, then one file of frame 0 changes under the writer (a bad disk, a stray
    process): the dataset must not be called complete."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def as_completed(self, handles):
        for h, entry in super().as_completed(handles):
            if entry["index"] == 0:
                (self.root / "frames" / "000000" / "truth.json").write_text("{}")
            yield h, entry


def test_generate_marks_complete_only_when_every_frame_verifies(tmp_path):
    out = tmp_path / "ds"
    with pytest.raises(DataFileError, match="frame 0: file truth.json differs"):
        generate(small_scenario(frames=2), out, options=DatasetOptions(radiance=False),
                 runner=_CorruptingRunner(out))
    assert json.loads((out / F.MANIFEST).read_text())["complete"] is False


# --------------------------------------------------------------------------- worker death
#: The frame whose writer dies, and when: after its temporary directory holds truth.json and
#: the radiance, as the first DN image is about to be written.
_DOOMED_FRAME = 3


def _arm_worker_death(marker: str) -> None:
    """Run on every worker (``client.run``): the first worker that writes frame
    ``_DOOMED_FRAME``'s DN image SIGKILLs itself there, once for the whole cluster (the marker
    file). Its nanny starts a fresh worker process, which is not armed."""
    import starnav.dataset.writer as w

    real = w.write_dn_png

    def dying_write(image, path, *args, **kwargs):
        frame_tmp = Path(path).parent.parent.name
        if frame_tmp.startswith(f"{F.TMP_PREFIX}{F.frame_dirname(_DOOMED_FRAME)}-"):
            die_once(marker, frame_tmp)
        return real(image, path, *args, **kwargs)

    w.write_dn_png = dying_write


@pytest.mark.slow
def test_a_worker_killed_mid_frame_leaves_no_temporary_and_verifies(tmp_path):
    """The worker writing frame 3 is killed (SIGKILL) with the frame half written in its
    temporary directory; the nanny restarts it, the scheduler re-runs the frame elsewhere.
    Deterministic: the kill happens at a fixed point of the frame writer, not on a timer."""
    from starnav.batch.cluster import open_runner

    sc = small_scenario(frames=6)
    ref = tmp_path / "ref"
    generate(sc, ref, options=OPTS)
    out = tmp_path / "killed"
    marker = tmp_path / "killed-once"
    with open_runner(workers=2) as runner:
        runner.client.run(_arm_worker_death, str(marker))
        s = generate(sc, out, options=OPTS, runner=runner)
    left = marker.read_text()  # the worker died inside this temporary frame directory
    assert left.startswith(F.TMP_PREFIX + F.frame_dirname(_DOOMED_FRAME))
    assert s.frames == 6
    assert [p.name for p in (out / "frames").iterdir() if p.name.startswith(".")] == []
    assert json.loads((out / F.MANIFEST).read_text())["complete"] is True
    assert verify(out) == []
    a, b = tree_bytes(ref), tree_bytes(out)
    assert [k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)] == []


# --------------------------------------------------------------------------- fsync
def test_atomic_writes_fsync_the_file_before_the_rename_and_the_directory_after(
        tmp_path, monkeypatch):
    import starnav.atomic as atomic

    events: list[tuple[str, str]] = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd: int) -> None:
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        real_fsync(fd)

    def replace(a, b) -> None:
        events.append(("rename", str(b)))
        real_replace(a, b)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    target = tmp_path / "sub" / "x.json"
    atomic.atomic_write_text(target, "{}")
    assert target.read_text() == "{}"
    kinds = [k for k, _ in events]
    assert kinds == ["fsync", "rename", "fsync"], events
    assert Path(events[0][1]).parent == target.parent and events[0][1] != str(target)
    assert events[1][1] == str(target)
    assert events[2][1] == str(target.parent)  # the directory holding the new name
