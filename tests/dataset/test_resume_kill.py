"""Crash safety: ``kill -9`` of ``starnav dataset`` at random points, then ``--resume``.

After every kill the directory must hold only whole frames (a frame directory has every file and
each parses) and a readable manifest listing whole frames only; after the final resume the
dataset must be byte-identical to an uninterrupted run with the same seed. Both runs are made on
one machine: byte identity is what the writer promises there (across CPUs the renders differ
in float32 rounding: tests/golden/pin.py).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from starnav.dataset import format as F
from starnav.dataset import verify

from .conftest import STARNAV, tree_bytes, write_small_yaml

FRAMES = 24
ARGS = ["--exposures", "1.5e-5,7.7e-3"]
#: Kills before the final resume.
KILLS = 3


def _run(yml: Path, out: Path, resume: bool) -> subprocess.Popen:
    cmd = [STARNAV, "dataset", str(yml), "--out", str(out), *ARGS] + (["--resume"] if resume
                                                                       else [])
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env=dict(os.environ), start_new_session=True)


def _frames_on_disk(out: Path) -> list[Path]:
    d = out / F.FRAMES_DIR
    return sorted(p for p in d.iterdir() if F.is_frame_dirname(p.name)) if d.is_dir() else []


def _check_whole(out: Path) -> None:
    """Every finished frame directory is complete and readable; the manifest lists whole
    frames only."""
    import imageio.v3 as iio

    from starnav.radiance import read_exr

    for d in _frames_on_disk(out):
        json.loads((d / F.TRUTH).read_text())
        assert read_exr(d / F.RADIANCE).Le.shape == (128, 128)
        for e in ("exposure_0.015ms", "exposure_7.7ms"):
            assert iio.imread(d / e / F.DN).shape == (128, 128)
            for name in (F.SEGMENTS, F.WINDOWS, F.READOUT):
                json.loads((d / e / name).read_text())
    man = json.loads((out / F.MANIFEST).read_text())
    listed = {e["directory"].split("/")[-1] for e in man["frames"]}
    assert listed <= {d.name for d in _frames_on_disk(out)}
    # a kill inside an atomic write leaves its temporary file (never the target half-written);
    # verify names it, and the resume removes it (checked after the final run)
    problems = [p for p in verify(out)
                if not p.startswith(("unfinished", "incomplete", "temporary file "))]
    assert problems == []


@pytest.mark.slow
def test_kill_minus_nine_then_resume_is_byte_identical(tmp_path):
    yml = write_small_yaml(tmp_path / "s.yaml", frames=FRAMES)
    ref = tmp_path / "ref"
    p = _run(yml, ref, resume=False)
    assert p.wait(timeout=300) == 0, p.stderr.read().decode()
    assert verify(ref) == []

    out = tmp_path / "killed"
    rng = np.random.default_rng(20250101)  # the test's own kill schedule, reproducible
    kills = 0
    for _attempt in range(KILLS + 3):
        if kills == KILLS:
            break
        n0 = len(_frames_on_disk(out))
        if n0 >= FRAMES - 1:
            break
        p = _run(yml, out, resume=True)
        # wait until this run makes progress (set-up takes a few seconds), then kill it at a
        # random point while frames are being written
        t0 = time.monotonic()
        while len(_frames_on_disk(out)) <= n0 and p.poll() is None \
                and time.monotonic() - t0 < 120:
            time.sleep(0.02)
        time.sleep(float(rng.uniform(0.0, 0.5)))
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(timeout=30)
            kills += 1
        _check_whole(out)
    assert kills >= 2, "the runs finished before they could be killed"
    assert len(_frames_on_disk(out)) < FRAMES
    p = _run(yml, out, resume=True)
    assert p.wait(timeout=300) == 0, p.stderr.read().decode()
    assert verify(out) == []
    assert not any(x.name.startswith(F.TMP_PREFIX) for x in (out / F.FRAMES_DIR).iterdir())
    a, b = tree_bytes(ref), tree_bytes(out)
    assert sorted(a) == sorted(b)
    assert [k for k in a if a[k] != b[k]] == []
