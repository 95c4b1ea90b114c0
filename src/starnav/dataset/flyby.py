"""A fly-by dataset read back and navigated through the fly-by closed loop.

A fly-by's windows follow each run's tracks, so its dataset stores per frame what every run
starts from: the radiance with the renderer's AOVs and ``truth.json`` (docs/dataset.md,
"Fly-by datasets").

1. :func:`read_flyby`: the manifest, the dataset's scenario with the ``navigation.*`` /
   ``seed`` overrides (:data:`NAVIGATE_KEYS`), and every frame as the ``(FrameGeometry,
   RadianceImage)`` pair the closed loop renders (geometry checked against the scenario's).
2. Navigated by :func:`starnav.batch.flyby.navigate_flyby_dataset`: its runs equal those of
   ``starnav navigate SCENARIO.yaml`` with the same seed.

Index
-----
:func:`read_flyby`, :func:`is_flyby_dataset`, :data:`NAVIGATE_KEYS`.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from starnav.config import scenario_from_dict
from starnav.dataset import format as F
from starnav.dataset.reader import check_layout, checked_file, read_manifest
from starnav.errors import ConfigError, DataFileError
from starnav.geometry import FrameGeometry
from starnav.radiance import RadianceImage, read_exr
from starnav.simulate.flyby import check_flyby_scenario
from starnav.simulate.frames import Simulator

#: ``--set`` keys a fly-by dataset's navigation may change (the frames are already rendered).
NAVIGATE_KEYS = ("navigation.", "seed")


def is_flyby_dataset(path: str | os.PathLike[str]) -> bool:
    """Whether the directory ``path`` holds a fly-by dataset (its manifest says
    ``target_kind: "flyby"``)."""
    root = Path(path)
    return (root / F.MANIFEST).is_file() and read_manifest(root).get("target_kind") == "flyby"


def read_flyby(path: str | os.PathLike[str], overrides: Sequence[str] = ()
               ) -> tuple[Simulator, list[tuple[FrameGeometry, RadianceImage]]]:
    """The dataset's scenario (with ``overrides``) as a Simulator and its frames read back
    (module step 1).

    Raises
    ------
    DataFileError
        Not a complete fly-by dataset, a missing radiance, a frame whose stored epoch is
        not the scenario's.
    ConfigError
        An override of anything but ``navigation.*`` or ``seed``.
    """
    root = Path(path)
    man = read_manifest(root)
    if man.get("target_kind") != "flyby":
        raise DataFileError(f"dataset {str(root)!r} is not a fly-by dataset (no target_kind "
                            "'flyby' in its manifest); navigate it with the limb chain")
    if not man.get("complete"):
        raise DataFileError(
            f"dataset {str(root)!r} is incomplete ({len(man.get('frames', []))} of "
            f"{man.get('frames_expected')} frames): finish it with `starnav dataset ... "
            "--resume`")
    for item in overrides:
        key = str(item).split("=", 1)[0].strip()
        if not (key == "seed" or key.startswith("navigation.")):
            raise ConfigError("--set", item, "a navigation.* or seed override: the fly-by "
                              "dataset's frames are already rendered (make a new dataset "
                              f"to change {key.split('.')[0]}.*)")
    sc = scenario_from_dict(man["config"], list(overrides))
    check_flyby_scenario(sc)
    if sc.navigation.trn.dispersion != "none":
        raise ConfigError("navigation.trn.dispersion", sc.navigation.trn.dispersion,
                          "'none' for a fly-by dataset: its frames are one fly-by; a "
                          "dispersed Monte Carlo renders each run's own (navigate the "
                          "scenario YAML)")
    check_layout(root, man)
    sim = Simulator(sc)
    if len(man["frames"]) != len(sim):
        raise DataFileError(f"dataset {str(root)!r}: {len(man['frames'])} frames, its scenario "
                            f"has {len(sim)}")
    renders = []
    for e in man["frames"]:
        d = root / e["directory"]
        geom = F.geometry_of_truth(F.read_json(checked_file(d, e, F.TRUTH)), d / F.TRUTH)
        want = float(sim.scene.epochs[int(e["index"])])
        if int(geom.index) != int(e["index"]) or float(geom.epoch_tdb) != want:
            raise DataFileError(f"{str(d / F.TRUTH)!r}: frame {geom.index} at epoch "
                                f"{geom.epoch_tdb!r} TDB s, the scenario's frame {e['index']} "
                                f"is at {want!r}")
        p = checked_file(d, e, F.RADIANCE, missing="a fly-by dataset needs every frame's "
                         "radiance")
        renders.append((geom, read_exr(p)))
    return sim, renders
