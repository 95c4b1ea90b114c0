"""Dataset generation and reading: layout, manifest, reader protocols, determinism, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

import starnav.dataset as ds
from starnav.dataset import DatasetOptions, generate, verify
from starnav.dataset import format as F
from starnav.errors import ConfigError, DataFileError

from .conftest import small_scenario, tree_bytes


def test_layout_manifest_and_verification(small_dataset):
    root = small_dataset
    man = json.loads((root / "manifest.json").read_text())
    assert man["schema"] == "starnav-dataset" and man["schema_version"] == F.SCHEMA_VERSION
    assert man["complete"] is True and man["frames_done"] == man["frames_expected"] == 4
    assert [e["index"] for e in man["frames"]] == [0, 1, 2, 3]
    assert man["software"]["variant"].endswith("spectral")
    assert man["camera"]["width_px"] == 128
    assert man["sun"]["band_electron_irradiance_1au_e_s_m2"] > 1e20
    assert [e["directory"] for e in man["exposures"]] == ["exposure_0.015ms", "exposure_7.7ms"]
    # the 0.015 ms exposure cannot read a full frame on the AA-STR (readout law)
    law = man["exposures"][0]["readout_law"]
    assert law[0]["mode"] == "segments" and law[0]["feasible"] is False
    assert (root / "scenario.resolved.yaml").is_file()
    for e in man["frames"]:
        d = root / e["directory"]
        names = {p.relative_to(d).as_posix() for p in d.rglob("*") if p.is_file()}
        assert names == set(e["files"])
        assert {"truth.json", "radiance.exr", "exposure_0.015ms/dn.png",
                "exposure_0.015ms/segments.json", "exposure_0.015ms/windows.json",
                "exposure_0.015ms/readout.json", "exposure_7.7ms/dn.png"} <= names
    assert verify(root) == []


def test_verify_finds_a_corrupted_file(small_dataset, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(small_dataset, copy)
    p = copy / "frames" / "000002" / "exposure_7.7ms" / "segments.json"
    p.write_text(p.read_text().replace("[", "[ ", 1))
    problems = verify(copy)
    assert len(problems) == 1 and "frame 2" in problems[0] and "segments.json" in problems[0]


def test_reader_implements_the_navigation_protocols(small_dataset):
    from starnav.navigation.frames import NavDataset, NavFrame

    data = ds.open(small_dataset)
    assert isinstance(data, NavDataset) and len(data) == 4
    assert data.exposure_time == 1.5e-5 and data.exposure_times == (1.5e-5, 7.7e-3)
    frames = list(data)
    assert all(isinstance(f, NavFrame) for f in frames)
    assert np.all(np.diff([f.epoch_tdb for f in frames]) == 1800.0)
    f = frames[1]
    assert f.truth.index == 1 and f.truth.camera_state_emb is not None
    assert np.allclose(np.linalg.norm(f.sun_direction_inertial), 1.0)
    assert f.segments.n_pixels > 100 and 1 <= len(f.windows) <= 16
    dn = f.dn()
    assert dn.dtype == np.uint16 and dn.shape == (128, 128)
    # the segments are the pixels of the DN frame at or above the threshold
    th = f.segments.thresholds[0]
    assert np.array_equal(f.segments.to_image(), np.where(dn >= th, dn, 0))
    rad = f.radiance()
    assert rad.Le.shape == (128, 128) and rad.Le.max() > 0
    # another exposure of the same frames
    sat = data.select(7.7e-3)
    assert sat[1].dn().max() == 4095 and dn.max() < 4095
    with pytest.raises(ConfigError, match="0.2"):
        data.select(0.2)


def test_navigation_runs_on_the_dataset(small_dataset, tmp_path):
    from starnav.navigation.report import navigate_dataset

    s = navigate_dataset(ds.open(small_dataset), tmp_path / "nav", plots=False,
                         measure_memory=False)
    assert s["frames"] == 4 and s["fixes"] >= 3
    # 0.015 ms: pixel-accurate limb (docs/facts.md s5), here with the windows' refinement
    assert abs(s["limb_error_px"]["bias"]) < 0.5


def test_each_exposure_equals_a_dataset_made_with_it_alone(small_dataset, tmp_path):
    """Common random numbers: exposure k of a multi-exposure dataset does not depend on the
    other exposures."""
    out = tmp_path / "alone"
    generate(small_scenario(), out, options=DatasetOptions(exposures_s=(7.7e-3,)))
    for i in range(4):
        a = tree_bytes(small_dataset / "frames" / f"{i:06d}" / "exposure_7.7ms")
        b = tree_bytes(out / "frames" / f"{i:06d}" / "exposure_7.7ms")
        assert a == b
        assert ((small_dataset / "frames" / f"{i:06d}" / "radiance.exr").read_bytes()
                == (out / "frames" / f"{i:06d}" / "radiance.exr").read_bytes())


def test_exposure_overrides_apply_to_one_exposure(tmp_path):
    out = tmp_path / "ov"
    opts = DatasetOptions(exposures_s=(1.5e-5, 7.7e-3), radiance=False, exposure_overrides=(
        (7.7e-3, ("detector.readout.segments.thresholds_dn=[2048]",)),))
    generate(small_scenario(frames=1), out, options=opts)
    d = ds.open(out)
    assert d[0].segments.thresholds == (200,)
    assert d.select(7.7e-3)[0].segments.thresholds == (2048,)
    assert d.select(7.7e-3)[0].readout["overrides"] == [
        "detector.readout.segments.thresholds_dn=[2048]"]
    assert not (out / "frames" / "000000" / "radiance.exr").exists()
    with pytest.raises(ConfigError, match="detector"):
        DatasetOptions(exposures_s=(1e-3,), exposure_overrides=(
            (1e-3, ("moon.albedo=0.3",)),)).resolved(small_scenario())


def test_bad_output_directories(tmp_path, small_dataset):
    sc = small_scenario(frames=1)
    a_file = tmp_path / "file"
    a_file.write_text("x")
    with pytest.raises(DataFileError, match="not a directory"):
        generate(sc, a_file / "sub")
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(DataFileError, match="not a starnav dataset"):
        generate(sc, foreign)
    assert sorted(p.name for p in foreign.iterdir()) == ["notes.txt"]  # untouched
    with pytest.raises(DataFileError, match="--resume"):
        generate(small_scenario(), small_dataset,
                 options=DatasetOptions(exposures_s=(1.5e-5, 7.7e-3)))
    with pytest.raises(ConfigError, match="seed"):
        generate(small_scenario().model_copy(update={"seed": 3}), small_dataset, resume=True,
                 options=DatasetOptions(exposures_s=(1.5e-5, 7.7e-3)))
    with pytest.raises(DataFileError, match="does not exist"):
        ds.open(tmp_path / "nowhere")


def test_incomplete_dataset_is_refused_unless_asked(tmp_path):
    out = tmp_path / "part"

    class Boom(Exception):
        """The crash injected into the generator."""

    def progress(done, total):
        if done == 2:
            raise Boom

    with pytest.raises(Boom):
        generate(small_scenario(frames=6), out, options=DatasetOptions(radiance=False),
                 progress=progress)
    man = json.loads((out / "manifest.json").read_text())
    assert man["complete"] is False and man["frames_done"] == 2
    with pytest.raises(DataFileError, match="incomplete"):
        ds.open(out)
    assert len(ds.open(out, allow_incomplete=True)) == 2
    # the frames already in flight in the other threads when the crash came (at most
    # FRAME_THREADS + 1 ahead) land whole: FrameMaker.making_ahead waits for them; the resume
    # makes the others
    on_disk = len([p for p in (out / "frames").iterdir() if F.is_frame_dirname(p.name)])
    assert 2 <= on_disk < 6
    s = generate(small_scenario(frames=6), out, options=DatasetOptions(radiance=False),
                 resume=True)
    assert s.frames_made == 6 - on_disk and verify(out) == []


def _profile_enabled() -> bool:
    import dask

    return bool(dask.config.get("distributed.worker.profile.enabled"))


@pytest.mark.slow
def test_one_and_two_workers_give_identical_datasets(tmp_path):
    """On one machine (the workers share its CPU, so Dr.Jit compiles the same kernels), 1 and
    2 workers write byte-identical datasets."""
    from starnav.batch.cluster import local_worker_config, open_runner

    opts = DatasetOptions(exposures_s=(1.5e-5, 7.7e-3))
    generate(small_scenario(frames=6), tmp_path / "one", options=opts)
    with open_runner(workers=2) as runner:
        s = generate(small_scenario(frames=6), tmp_path / "two", options=opts, runner=runner)
        # the local cluster's workers run without Dask's statistical profiler (issue 18:
        # ~5 % of a sweep's CPU), unless the environment says otherwise
        want = local_worker_config().get("distributed.worker.profile.enabled", True)
        assert set(runner.client.run(_profile_enabled).values()) == {want}
    assert s.runner.startswith("local cluster")
    assert tree_bytes(tmp_path / "one") == tree_bytes(tmp_path / "two")


def test_dataset_cli_exposures_and_summary(tmp_path):
    from typer.testing import CliRunner

    from starnav.cli.main import app  # the real command line

    from .conftest import write_small_yaml

    yml = write_small_yaml(tmp_path / "s.yaml", frames=2)
    out = tmp_path / "cli"
    r = CliRunner().invoke(app, ["dataset", str(yml), "--out", str(out), "--exposures",
                                 "1.5e-5,7.7e-3", "--no-radiance"])
    assert r.exit_code == 0, r.output
    assert "frames/s" in r.output and "exposure_7.7ms" in r.output
    assert verify(out) == []
    r = CliRunner().invoke(app, ["dataset", str(yml), "--out", str(out), "--exposures", "x"])
    assert r.exit_code == 2 and "--exposures" in r.output
    r = CliRunner().invoke(app, ["dataset", str(yml), "--out", str(out)])
    assert r.exit_code == 2 and "--resume" in r.output




def test_resume_after_a_crash_inside_a_frame(small_dataset, tmp_path):
    """What kill -9 leaves mid-frame (a temporary frame directory, a stale manifest) is cleaned
    up and the frame remade byte for byte."""
    import shutil

    out = tmp_path / "crashed"
    shutil.copytree(small_dataset, out)
    frames = out / "frames"
    shutil.rmtree(frames / "000002")
    partial = frames / ".tmp-000002-abcd"
    (partial / "exposure_0.015ms").mkdir(parents=True)
    (partial / "truth.json").write_text("{")  # half written
    (out / ".manifest.json.x1y2.json").write_text('{"sche')  # an interrupted manifest write
    man = json.loads((out / "manifest.json").read_text())
    man["frames"] = [e for e in man["frames"] if e["index"] < 2]
    man["frames_done"], man["complete"] = 2, False
    (out / "manifest.json").write_text(F.dumps(man))
    assert any("unfinished" in p for p in verify(out))
    s = generate(small_scenario(), out, options=DatasetOptions(exposures_s=(1.5e-5, 7.7e-3)),
                 resume=True)
    assert s.frames_made == 1  # frame 3 was on disk: re-indexed from its files, not remade
    assert not partial.exists() and verify(out) == []
    assert tree_bytes(out) == tree_bytes(small_dataset)


def test_a_second_writer_is_locked_out(tmp_path):
    import fcntl

    from starnav.dataset.writer import DatasetLockedError

    out = tmp_path / "locked"
    out.mkdir()
    with open(out / ".lock", "a+") as fh:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(DatasetLockedError, match="another process"):
            generate(small_scenario(frames=1), out)
        assert (out / ".lock").exists()  # the holder's lock is left alone


def test_frames_made_ahead_in_threads_keep_the_bytes(tmp_path):
    """In-process generation makes FRAME_THREADS frames at once, each in its own thread
    (writer module step 3): the frames are made outside the calling thread, two at a time,
    write their files one frame at a time in the announced order, and are byte for byte those
    made one at a time; a frame asked for out of the announced order is still the right one,
    and nothing is left running or half-written on exit."""
    import threading
    import time

    from starnav.dataset.writer import FrameMaker

    sc = small_scenario(frames=5)
    opts = DatasetOptions(exposures_s=(1.5e-5, 7.7e-3))
    serial = FrameMaker(sc, opts)
    for i in range(5):
        serial.write_frame(i, tmp_path / "serial")
    ahead = FrameMaker(sc, opts)
    made: list[tuple[int, str]] = []
    running, overlap = [0], [0]
    lock = threading.Lock()
    write = ahead._write_frame

    def spy(index, root):
        with lock:
            made.append((index, threading.current_thread().name))
            running[0] += 1
            overlap[0] = max(overlap[0], running[0])
        try:
            time.sleep(0.2)   # long enough for the next frame to start meanwhile
            return write(index, root)
        finally:
            with lock:
                running[0] -= 1

    ahead._write_frame = spy
    written: list[int] = []
    write_files = ahead._write_files

    def spy_files(index, *args):
        with lock:
            written.append(index)
        return write_files(index, *args)

    ahead._write_files = spy_files
    root = tmp_path / "ahead"
    with ahead.making_ahead([0, 1, 2, 3], root, threads=2):
        assert ahead.write_frame(0, root)["index"] == 0
        assert ahead.write_frame(4, root)["index"] == 4   # not announced: this thread
        for i in (1, 2, 3):
            assert ahead.write_frame(i, root)["index"] == i
    assert ahead._started == {} and ahead._pool is None
    main = threading.current_thread().name
    assert sorted(i for i, _ in made) == [0, 1, 2, 3, 4]
    assert all(name.startswith("starnav-frame") for i, name in made if i != 4)
    assert (4, main) in made
    assert overlap[0] >= 2   # two frames (at least) were being made at once
    assert [i for i in written if i != 4] == [0, 1, 2, 3]   # they land in the announced order
    assert tree_bytes(root) == tree_bytes(tmp_path / "serial")
    assert not [p for p in (root / "frames").iterdir() if p.name.startswith(F.TMP_PREFIX)]


def test_frames_asked_for_out_of_order_while_others_are_made_ahead(tmp_path):
    """A caller that asks for frames in another order than it announced gets every frame
    right, with no deadlock: a frame behind the frames already started is made in the calling
    thread, the others ahead; the bytes are those of the serial order."""
    import threading

    from starnav.dataset.writer import FrameMaker

    sc = small_scenario(frames=6)
    opts = DatasetOptions(exposures_s=(1.5e-5,), radiance=False)
    serial = FrameMaker(sc, opts)
    for i in range(6):
        serial.write_frame(i, tmp_path / "serial")
    ahead = FrameMaker(sc, opts)
    root = tmp_path / "ahead"
    got: list[int] = []

    def run():
        with ahead.making_ahead(range(6), root, threads=2):
            for i in (3, 0, 4, 1, 5, 2, 3):   # 3 twice: the second call finds it on disk
                got.append(ahead.write_frame(i, root)["index"])

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(timeout=120)
    assert not t.is_alive(), "deadlock"
    assert got == [3, 0, 4, 1, 5, 2, 3]
    assert tree_bytes(root) == tree_bytes(tmp_path / "serial")
