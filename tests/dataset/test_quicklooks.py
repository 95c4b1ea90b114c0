"""Every DN frame of a dataset and every EXR of ``starnav render`` has its 8-bit quick look."""

from __future__ import annotations

import json

import numpy as np
from PIL import Image

from starnav.dataset import format as F
from starnav.dataset import open as open_dataset
from starnav.quicklook import QUICKLOOK_BAR_PX, QUICKLOOK_CAPTION_PX
from starnav.radiance import read_exr
from starnav.simulate import render_to_directory
from starnav.simulate.frames import quicklook_name

from .conftest import small_scenario


def _lit_and_sky(a: np.ndarray, lit: np.ndarray) -> tuple[float, float]:
    rows = slice(QUICKLOOK_CAPTION_PX, a.shape[0] - QUICKLOOK_BAR_PX - QUICKLOOK_CAPTION_PX - 2)
    a, lit = a[rows], lit[rows]
    return float(np.median(a[lit])), float(np.median(a[~lit]))


def test_each_dn_frame_has_its_quicklook(small_dataset):
    man = json.loads((small_dataset / F.MANIFEST).read_text())
    assert F.DN_QUICKLOOK in man["layout"]["per_exposure"]
    assert man["layout"]["radiance_quicklook"] == F.RADIANCE_QUICKLOOK
    for t in (1.5e-5, 7.7e-3):
        data = open_dataset(small_dataset, exposure=t)
        for frame in data:
            p = frame.exposure_dir / F.DN_QUICKLOOK
            assert p.name in {k.split("/")[-1] for k in frame.entry["files"]}
            im = Image.open(p)
            dn = frame.dn()
            assert im.mode == "L" and im.size == (dn.shape[1], dn.shape[0])
            a = np.asarray(im)
            # the lit Moon (pixels well above the sky in the data) bright, the sky black
            lit = dn > np.median(dn) + 200
            if lit.sum() < 20:
                continue
            moon, sky = _lit_and_sky(a, lit)
            assert moon >= 150 and sky <= 10, (t, frame.index, moon, sky)
            d = im.text["Description"]
            assert f"frame {frame.index}" in d and f"exp {t * 1e3:g} ms" in d
            assert "range" in d and "km" in d and "phase" in d and "asinh" in d
            # the data file is unchanged: 16-bit DN
            assert Image.open(frame.exposure_dir / F.DN).mode.startswith("I")


def test_radiance_quicklook_in_dataset_and_render(small_dataset, tmp_path):
    d = small_dataset / "frames" / "000000"
    im = Image.open(d / F.RADIANCE_QUICKLOOK)
    L = read_exr(d / F.RADIANCE).L
    assert im.mode == "L" and im.size == (L.shape[1], L.shape[0])
    assert im.text["starnav:unit"] == "W m^-2 sr^-1" and float(im.text["starnav:black"]) == 0
    paths = render_to_directory(small_scenario(frames=1), tmp_path / "r")
    q = tmp_path / "r" / quicklook_name(0)
    assert [p.name for p in paths] == ["frame_000000.exr"] and q.is_file()
    a = np.asarray(Image.open(q))
    L = read_exr(paths[0]).L
    moon, sky = _lit_and_sky(a, L > 0.2 * L.max())
    assert moon >= 150 and sky <= 10
