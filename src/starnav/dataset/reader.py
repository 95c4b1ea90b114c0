"""Reading a dataset: :func:`open` gives a :class:`Dataset`, a navigation ``NavDataset``.

:class:`Dataset` holds the manifest, the camera (rebuilt from the manifest's intrinsics, so it
does not depend on the scenario schema) and one selected exposure; iterating it yields
:class:`DatasetFrame` objects in time order, each a navigation ``NavFrame``
(:mod:`starnav.navigation.frames`) whose files are read on first access and cached, plus the
DN image, the radiance image and the raw JSON documents.

:func:`verify` re-hashes every file against the manifest and says what is missing or left
over by an interrupted run (``starnav dataset verify DIR``).

Example
-------
>>> import starnav.dataset as ds
>>> data = ds.open("out/ds", exposure=7.7e-3)                    # doctest: +SKIP
>>> f = data[0]; f.segments, f.windows, f.truth.range            # doctest: +SKIP
"""

from __future__ import annotations

import functools
import logging
import math
import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from starnav.cache import BoundedCache
from starnav.config import scenario_from_dict
from starnav.dataset import format as F
from starnav.detector.io import read_dn_png
from starnav.errors import ConfigError, DataFileError
from starnav.radiance import read_exr
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Files already checked against their manifest entry, by (path, size, mtime, SHA-256): a file
#: read again (a Monte Carlo run re-reading a frame's radiance) is hashed once.
_CHECKED: BoundedCache[tuple[str, int, int, str], bool] = BoundedCache(4096, policy="fifo")


def checked_file(frame_dir: Path, entry: dict[str, Any], rel: str, *,
                 optional: bool = False, missing: str = "") -> Path | None:
    """The path of the frame's file ``rel`` once it matches its manifest ``entry``.

    A file the manifest lists must be there with its size and SHA-256; a file it does not
    list must be absent (then None when ``optional``, e.g. the segments of a frame whose
    segments readout sent nothing). Anything else is a :class:`DataFileError` naming the file:
    a dataset changed after it was made is refused, not read as something else (a deleted
    ``windows.json`` is not "no windows"). ``missing`` says why a required file is needed.
    """
    p = Path(frame_dir) / rel
    meta = (entry.get("files") or {}).get(rel)
    verify_hint = "; `starnav dataset verify` lists every such file"
    if meta is None:
        if p.is_file():
            raise DataFileError(f"{str(p)!r} is not in the dataset's manifest: added after the "
                                f"dataset was made{verify_hint}")
        if optional:
            return None
        raise DataFileError(f"{str(p)!r} does not exist and the manifest does not list it"
                            + (f": {missing}" if missing else ""))
    if not p.is_file():
        raise DataFileError(f"{str(p)!r} is missing (the manifest lists it, {meta['bytes']} "
                            f"bytes){verify_hint}")
    st = p.stat()
    key = (str(p), st.st_size, st.st_mtime_ns, str(meta["sha256"]))
    if key not in _CHECKED:
        if st.st_size != meta["bytes"] or F.sha256_file(p) != meta["sha256"]:
            raise DataFileError(f"{str(p)!r} differs from the dataset's manifest (size or "
                                f"SHA-256): changed after the dataset was made{verify_hint}")
        _CHECKED.put(key, True)
    return p


def _read_only(a: FloatArray) -> FloatArray:
    a.flags.writeable = False
    return a


class DatasetFrame:
    """One frame of a dataset at one exposure (a ``NavFrame``; files read lazily).

    Attributes
    ----------
    index : int
    epoch_tdb : float
        [TDB s past J2000].
    directory : Path
        The frame's directory.
    exposure_dir : Path
        The selected exposure's directory.
    """

    def __init__(self, root: Path, entry: dict[str, Any], exposure_dirname: str) -> None:
        self.index = int(entry["index"])
        self.epoch_tdb = float(entry["epoch_tdb_s"])
        self.entry = entry
        self.directory = root / entry["directory"]
        self.exposure_dir = self.directory / exposure_dirname

    def __repr__(self) -> str:
        return f"DatasetFrame(index={self.index}, exposure_dir={self.exposure_dir.name!r})"

    # ------------------------------------------------------------------ raw documents
    def _file(self, rel: str, optional: bool = False, missing: str = "") -> Path | None:
        """The frame's file ``rel`` (relative to its directory) once it matches the manifest
        (:func:`checked_file`)."""
        return checked_file(self.directory, self.entry, rel, optional=optional,
                            missing=missing)

    def _exposure_file(self, name: str, optional: bool = False) -> Path | None:
        return self._file(f"{self.exposure_dir.name}/{name}", optional)

    def _truth(self, key: str, shape: tuple[int, ...] | None = None) -> Any:
        """The value at the dotted ``key`` of ``truth.json`` (a missing or malformed key: an
        error naming the file and the key)."""
        return F.json_value(self.truth_dict, key, self.directory / F.TRUTH, shape)

    @functools.cached_property
    def truth_dict(self) -> dict[str, Any]:
        """``truth.json`` as a dict."""
        return F.read_json(self._file(F.TRUTH))

    @functools.cached_property
    def readout(self) -> dict[str, Any]:
        """``readout.json`` of the selected exposure."""
        return F.read_json(self._exposure_file(F.READOUT))

    # ------------------------------------------------------------------ NavFrame
    @functools.cached_property
    def truth(self) -> Any:
        """True pose: :class:`~starnav.geometry.FrameGeometry` (Moon-centred, SI)."""
        return F.geometry_of_truth(self.truth_dict, self.directory / F.TRUTH)

    # the frame's attitude and Sun: read once (the chain asks for them at every stage),
    # read-only so that no caller changes what the next one reads
    @functools.cached_property
    def R_cam_to_inertial_measured(self) -> FloatArray:
        """On-board attitude, camera -> J2000 (true attitude if none was stored)."""
        a = self._truth("attitude")
        key = ("attitude.R_cam_to_inertial_measured"
               if isinstance(a, dict) and a.get("R_cam_to_inertial_measured") is not None
               else "attitude.R_cam_to_inertial_true")
        return _read_only(self._truth(key, (3, 3)))

    @functools.cached_property
    def sun_direction_inertial(self) -> FloatArray:
        """Unit vector from the Moon to the Sun, J2000."""
        return _read_only(self._truth("sun.direction_from_moon", (3,)))

    @functools.cached_property
    def R_body_to_inertial(self) -> FloatArray:
        """Moon body-fixed -> J2000."""
        return _read_only(self._truth("moon.R_moon_to_inertial", (3, 3)))

    @functools.cached_property
    def segments(self) -> Any:
        """:class:`~starnav.detector.products.Segments` of acquisition 0 (None if the frame
        has none: the manifest does not list its file)."""
        p = self._exposure_file(F.SEGMENTS, optional=True)
        if p is None:
            return None
        return F.segments_from_dict(F.read_json(p))

    @functools.cached_property
    def windows(self) -> tuple[Any, ...]:
        """Windows (:class:`~starnav.detector.products.Window`) read along the limb."""
        p = self._exposure_file(F.WINDOWS, optional=True)
        if p is None:
            return ()
        return F.windows_from_dict(F.read_json(p))

    # ------------------------------------------------------------------ images
    def dn(self) -> NDArray[np.uint16]:
        """Full DN frame of acquisition 0 [DN] (16-bit PNG)."""
        return read_dn_png(self._exposure_file(F.DN))

    def star_dn(self) -> NDArray[np.uint16] | None:
        """The star acquisition's DN frame [DN] (``stars_dn.png``: a scheduled star frame of a
        ``navigation.attitude.source: stars`` dataset), None when the frame has none."""
        p = self._exposure_file(F.STAR_DN, optional=True)
        return read_dn_png(p) if p is not None else None

    def radiance(self) -> Any:
        """:class:`~starnav.radiance.RadianceImage` (``radiance.exr``)."""
        return read_exr(self._file(F.RADIANCE, missing="the dataset was made without "
                                   "radiance (--no-radiance)"))

    @property
    def true_limb_px(self) -> FloatArray:
        """True limb points ``(n, 2)`` [px] (with the lens distortion)."""
        pts = self._truth("limb.points_px")
        try:
            a = np.asarray(pts, float).reshape(-1, 2)
        except (TypeError, ValueError):
            a = None
        if a is None or not np.isfinite(a).all():
            raise DataFileError(f"{str(self.directory / F.TRUTH)!r}: key 'limb.points_px': "
                                "expected finite (u, v) pairs")
        return a

    @property
    def emb_state(self) -> FloatArray | None:
        """Spacecraft state relative to the Earth-Moon barycentre, J2000 ``(6,)`` [m, m/s]."""
        if self._truth("spacecraft_emb") is None:
            return None
        return np.concatenate([self._truth("spacecraft_emb.position_m", (3,)),
                               self._truth("spacecraft_emb.velocity_m_s", (3,))])


class Dataset:
    """A dataset on disk at one exposure (a navigation ``NavDataset``).

    Attributes
    ----------
    path : Path
    manifest : dict
    camera : Camera
    exposure_time : float
        The selected exposure time [s].
    exposure_times : tuple of float
        Every exposure time the dataset holds [s].
    complete : bool
    """

    def __init__(self, path: Path, manifest: dict[str, Any], exposure_time: float) -> None:
        self.path = path
        self.manifest = manifest
        self.camera = F.camera_from_dict(manifest["camera"])
        self.exposure_times = tuple(float(e["exposure_s"]) for e in manifest["exposures"])
        self.exposure_time = float(exposure_time)
        self.exposure_dirname = F.exposure_dirname(self.exposure_time)
        self.complete = bool(manifest.get("complete"))
        self._entries = list(manifest["frames"])

    def __repr__(self) -> str:
        return (f"Dataset({str(self.path)!r}, frames={len(self)}, "
                f"exposure={self.exposure_time * 1e3:.6g} ms, complete={self.complete})")

    def __len__(self) -> int:
        return len(self._entries)

    def __iter__(self) -> Iterator[DatasetFrame]:
        for e in self._entries:
            yield DatasetFrame(self.path, e, self.exposure_dirname)

    def __getitem__(self, k: int) -> DatasetFrame:
        return DatasetFrame(self.path, self._entries[k], self.exposure_dirname)

    @property
    def config(self) -> dict[str, Any]:
        """The resolved scenario the dataset was made with (plain dict)."""
        return self.manifest["config"]

    @property
    def exposure_overrides(self) -> tuple[str, ...]:
        """The ``detector.*`` / ``navigation.*`` overrides the selected exposure was made
        with (e.g. the saturated exposures' segment threshold), as ``KEY=VALUE``."""
        for e in self.manifest["exposures"]:
            if abs(float(e["exposure_s"]) - self.exposure_time) <= 1e-9 * self.exposure_time:
                return tuple(str(x) for x in e.get("overrides", ()))
        return ()

    def scenario(self, overrides: Sequence[str] = ()) -> Any:
        """The resolved scenario of the selected exposure, validated
        (:class:`~starnav.config.Scenario`): the dataset's, with the exposure's time and its
        :attr:`exposure_overrides`, then ``overrides``."""
        return scenario_from_dict(self.config, [
            f"detector.exposure_time_s={self.exposure_time!r}", *self.exposure_overrides,
            *overrides])

    def select(self, exposure_time: float) -> Dataset:
        """The same dataset at another exposure time [s] (one of :attr:`exposure_times`)."""
        return Dataset(self.path, self.manifest, _pick_exposure(self.manifest, exposure_time))


    def verify(self) -> list[str]:
        """The problems of the dataset on disk (:func:`verify`; empty: complete and intact)."""
        return verify(self.path)

    def epochs(self) -> FloatArray:
        """Frame epochs [TDB s past J2000]."""
        return np.array([float(e["epoch_tdb_s"]) for e in self._entries])


def _pick_exposure(manifest: dict[str, Any], exposure: float | None) -> float:
    """The manifest's exposure time equal to ``exposure`` [s] (seconds only: an index would be
    ambiguous with a time), default the first."""
    exps = [float(e["exposure_s"]) for e in manifest["exposures"]]
    if not exps:
        raise DataFileError("the manifest lists no exposure")
    if exposure is None:
        return exps[0]
    if isinstance(exposure, bool) or not isinstance(exposure, int | float):
        raise ConfigError("exposure", exposure, "an exposure time in seconds")
    v = float(exposure)
    for t in exps:
        if math.isclose(t, v, rel_tol=1e-9):
            return t
    raise ConfigError("exposure", exposure,
                      "one of the dataset's exposure times [s]: "
                      + ", ".join(f"{t!r}" for t in exps))


def read_manifest(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The manifest of the dataset at ``path``, checked for schema and version."""
    root = Path(path)
    if not root.is_dir():
        raise DataFileError(f"dataset {str(root)!r} does not exist or is not a directory")
    man = F.read_json(root / F.MANIFEST)
    if man.get("schema") != F.SCHEMA:
        raise DataFileError(f"{str(root / F.MANIFEST)!r} is not a starnav dataset manifest")
    if int(man.get("schema_version", -1)) > F.SCHEMA_VERSION:
        raise DataFileError(f"dataset schema version {man.get('schema_version')} is newer than "
                            f"this starnav reads ({F.SCHEMA_VERSION}); update starnav")
    return man


def open(path: str | os.PathLike[str], exposure: float | None = None, *,  # noqa: A001
         allow_incomplete: bool = False) -> Dataset:
    """Open the dataset at ``path``.

    Parameters
    ----------
    path : path
        Dataset directory.
    exposure : float, optional
        Exposure time [s] (one of the dataset's); default the first.
    allow_incomplete : bool
        Open a dataset whose generation has not finished (only its finished frames).

    Raises
    ------
    DataFileError
        Not a dataset, unreadable, incomplete (unless ``allow_incomplete``), or a listed
        frame's files not those of the manifest (:func:`check_layout`).
    ConfigError
        ``exposure`` not in the dataset.
    """
    root = Path(path)
    man = read_manifest(root)
    if not man.get("complete") and not allow_incomplete:
        raise DataFileError(
            f"dataset {str(root)!r} is incomplete ({len(man.get('frames', []))} of "
            f"{man.get('frames_expected')} frames): finish it with `starnav dataset ... "
            "--resume`, or open it with allow_incomplete=True")
    if man.get("target_kind") == "flyby":
        raise DataFileError(
            f"dataset {str(root)!r} is a fly-by dataset (radiance and truth, no exposure: its "
            "windows depend on the previous frame's tracks); it is navigated only by the "
            "fly-by closed loop, `starnav navigate DATASET` (starnav.dataset.flyby), not by "
            "the limb chain")
    check_layout(root, man)
    return Dataset(root, man, _pick_exposure(man, exposure))


def check_layout(root: Path, man: dict[str, Any]) -> None:
    """Raise a :class:`DataFileError` naming the first file of a listed frame that is missing,
    unlisted or of another size than the manifest says (a cheap check, no hashing: the files
    read are hashed when read, :func:`checked_file`; :func:`verify` hashes them all)."""
    hint = "; `starnav dataset verify` lists every such file"
    for e in man["frames"]:
        d = root / e["directory"]
        if not d.is_dir():
            raise DataFileError(f"{str(d)!r} is missing (the manifest lists frame "
                                f"{e['index']}){hint}")
        files = e.get("files") or {}
        on_disk = {p.relative_to(d).as_posix(): p for p in d.rglob("*") if p.is_file()}
        for rel in sorted(set(files) - set(on_disk)):
            raise DataFileError(f"{str(d / rel)!r} is missing (the manifest lists it, "
                                f"{files[rel]['bytes']} bytes){hint}")
        for rel in sorted(set(on_disk) - set(files)):
            raise DataFileError(f"{str(d / rel)!r} is not in the dataset's manifest: added "
                                f"after the dataset was made{hint}")
        for rel, meta in sorted(files.items()):
            size = on_disk[rel].stat().st_size
            if size != meta["bytes"]:
                raise DataFileError(f"{str(d / rel)!r} differs from the dataset's manifest "
                                    f"({size} bytes, listed with {meta['bytes']}){hint}")


def verify(path: str | os.PathLike[str]) -> list[str]:
    """Check the dataset at ``path`` against its manifest (:func:`verify_manifest`); returns
    a list of problems (empty: the dataset is complete and intact)."""
    root = Path(path)
    return verify_manifest(root, read_manifest(root))


def _ranges(indices: Sequence[int]) -> str:
    """``[1, 2, 3, 7]`` -> ``"1-3, 7"``."""
    out: list[str] = []
    for i in sorted(indices):
        if out and out[-1][1] == i - 1:
            out[-1] = (out[-1][0], i)
        else:
            out.append((i, i))  # type: ignore[arg-type]
    return ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in out)  # type: ignore[misc]


def verify_manifest(root: Path, man: dict[str, Any]) -> list[str]:
    """Problems of the dataset at ``root`` against the manifest ``man`` (empty: intact).

    Reported: frames the manifest expects but does not list (an incomplete dataset: which
    ones, and how to finish it), listed frames whose directory or files are missing, differ
    in size or SHA-256, or hold unlisted files, or whose manifest entry differs from the
    frame's own record of its files (``files.json``); temporary files and frame directories left by
    an interrupted write; frame directories a complete manifest does not list.
    """
    problems: list[str] = []
    expected = int(man.get("frames_expected") or 0)
    indices = {int(e["index"]) for e in man["frames"]}
    missing = [i for i in range(expected) if i not in indices]
    if missing:
        problems.append(
            f"{'incomplete' if not man.get('complete') else 'manifest marked complete but'}: "
            f"{len(indices)} of {expected} frames (missing: {_ranges(missing)}); finish it "
            "with `starnav dataset SCENARIO --out DIR --resume`")
    elif not man.get("complete"):
        problems.append(f"incomplete: all {expected} frames listed but the manifest is not "
                        "marked complete; finish it with `starnav dataset SCENARIO --out DIR "
                        "--resume`")
    listed = set()
    for e in man["frames"]:
        d = root / e["directory"]
        listed.add(d.name)
        if not d.is_dir():
            problems.append(f"frame {e['index']}: directory {e['directory']} is missing")
            continue
        on_disk = {p.relative_to(d).as_posix() for p in d.rglob("*") if p.is_file()}
        for rel in sorted(on_disk - set(e["files"])):
            problems.append(f"frame {e['index']}: unlisted file {rel}")
        for rel, meta in e["files"].items():
            p = d / rel
            if not p.is_file():
                problems.append(f"frame {e['index']}: file {rel} is missing")
            elif p.stat().st_size != meta["bytes"] or F.sha256_file(p) != meta["sha256"]:
                problems.append(f"frame {e['index']}: file {rel} differs from the manifest")
        if F.FRAME_FILES in e["files"] and (d / F.FRAME_FILES).is_file():
            # the frame's own record, written with it (the files were checked against the
            # manifest above): a manifest entry rebuilt from a frame damaged before it was
            # listed differs from it
            try:
                rec = F.read_json(d / F.FRAME_FILES)["files"]
            except (DataFileError, KeyError, TypeError):
                rec = None
            listed_files = {k: v for k, v in e["files"].items() if k != F.FRAME_FILES}
            if rec != listed_files:
                names = sorted(k for k in set(rec or {}) | set(listed_files)
                               if (rec or {}).get(k) != listed_files.get(k))
                problems.append(f"frame {e['index']}: the manifest's files differ from the "
                                f"frame's own record ({F.FRAME_FILES}): "
                                f"{', '.join(names) or 'unreadable record'}")
    for name in (F.MANIFEST, F.RESOLVED):
        for p in root.glob(f".{name}.*"):
            problems.append(f"temporary file {p.name} left by an interrupted write (resume to "
                            "clean up)")
    frames = root / F.FRAMES_DIR
    if frames.is_dir():
        for p in sorted(frames.iterdir()):
            if p.name.startswith(F.TMP_PREFIX):
                problems.append(f"unfinished frame directory {F.FRAMES_DIR}/{p.name} (resume "
                                "to clean up)")
            elif F.is_frame_dirname(p.name) and p.name not in listed and man.get("complete"):
                problems.append(f"frame directory {p.name} is not in the manifest")
    return problems
