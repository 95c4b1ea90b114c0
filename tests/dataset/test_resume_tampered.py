"""``--resume`` adopts a frame left on disk only when it is whole, and ``verify`` does not
certify a damaged one.

What a kill between a frame's rename and the next manifest write leaves: frame directories on
disk that the manifest does not list. Damaged meanwhile (an edited segments.json, a dn.png cut
to 500 B, a deleted windows.json), each is checked against the record it carries
(``files.json``) and made again; the resumed dataset is byte-identical to an uninterrupted one.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from starnav.dataset import DatasetOptions, generate, verify
from starnav.dataset import format as F
from starnav.dataset.writer import frame_entry

from .conftest import small_dataset, small_scenario, tree_bytes  # noqa: F401

E7 = "exposure_7.7ms"
E0 = "exposure_0.015ms"


def _unlist(out: Path, keep: int) -> None:
    """The manifest as the last write before the kill left it: frames ``< keep`` listed."""
    man = json.loads((out / F.MANIFEST).read_text())
    man["frames"] = [e for e in man["frames"] if e["index"] < keep]
    man["frames_done"], man["complete"] = keep, False
    F.write_json(out / F.MANIFEST, man)


def _tamper(out: Path) -> None:
    frames = out / F.FRAMES_DIR
    seg = frames / "000001" / E7 / F.SEGMENTS
    text = seg.read_text()
    edited = text.replace("1", "2", 1)   # one digit: still valid JSON, same size
    assert edited != text and len(edited) == len(text)
    json.loads(edited)
    seg.write_text(edited)
    dn = frames / "000002" / E0 / F.DN
    dn.write_bytes(dn.read_bytes()[:500])
    (frames / "000003" / E7 / F.WINDOWS).unlink()


def test_resume_redoes_tampered_leftovers_and_verify_passes_only_after(small_dataset,  # noqa: F811
                                                                       tmp_path):
    out = tmp_path / "killed"
    shutil.copytree(small_dataset, out)
    _unlist(out, keep=1)
    _tamper(out)
    problems = verify(out)
    assert problems and "incomplete" in problems[0]
    s = generate(small_scenario(), out, options=DatasetOptions(exposures_s=(1.5e-5, 7.7e-3)),
                 resume=True)
    assert s.frames_made == 3  # the three damaged frames, none adopted
    assert verify(out) == []
    assert tree_bytes(out) == tree_bytes(small_dataset)  # as if never interrupted


def test_a_whole_leftover_is_adopted_without_remaking_it(small_dataset, tmp_path):  # noqa: F811
    out = tmp_path / "killed"
    shutil.copytree(small_dataset, out)
    _unlist(out, keep=1)
    s = generate(small_scenario(), out, options=DatasetOptions(exposures_s=(1.5e-5, 7.7e-3)),
                 resume=True)
    assert s.frames_made == 0
    assert tree_bytes(out) == tree_bytes(small_dataset)


def test_resume_redoes_a_listed_frame_damaged_after_it_was_listed(small_dataset,  # noqa: F811
                                                                  tmp_path):
    out = tmp_path / "damaged"
    shutil.copytree(small_dataset, out)
    _unlist(out, keep=4)     # all listed, not yet marked complete
    (out / F.FRAMES_DIR / "000000" / E7 / F.SEGMENTS).write_text("{}")
    assert any("000000" in p or "frame 0" in p for p in verify(out))
    s = generate(small_scenario(), out, options=DatasetOptions(exposures_s=(1.5e-5, 7.7e-3)),
                 resume=True)
    assert s.frames_made == 1 and verify(out) == []
    assert tree_bytes(out) == tree_bytes(small_dataset)


def test_verify_does_not_certify_a_frame_listed_from_damaged_files(small_dataset,  # noqa: F811
                                                                   tmp_path):
    """A manifest whose entries were rebuilt from damaged files (what adopting them blindly
    wrote) passes the size and hash checks against itself; the frames' own records catch it."""
    out = tmp_path / "certified"
    shutil.copytree(small_dataset, out)
    _tamper(out)
    man = json.loads((out / F.MANIFEST).read_text())
    man["frames"] = [frame_entry(out, e["index"]) for e in man["frames"]]
    F.write_json(out / F.MANIFEST, man)
    problems = verify(out)
    for i, name in ((1, f"{E7}/{F.SEGMENTS}"), (2, f"{E0}/{F.DN}"), (3, f"{E7}/{F.WINDOWS}")):
        assert any(p.startswith(f"frame {i}:") and name in p for p in problems), (i, problems)
    assert not any(p.startswith("frame 0:") for p in problems)
