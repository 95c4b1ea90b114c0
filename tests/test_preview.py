"""Preview pictures (starnav.preview): the stretch, the encoding and the layout, on frames whose
radiance is known exactly (no renderer needed)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.errors import ConfigError
from starnav.preview import (
    radiance_stretch,
    srgb_encode,
    write_previews,
    write_radiance_preview,
)
from starnav.radiance import RadianceImage, write_exr

#: IEC 61966-2-1: linear 0.5 encodes to 0.7354 (188/255), linear 0.18 to 0.4614 (118/255).
SRGB_REFERENCE = ((0.0, 0.0), (0.0031308, 0.04045), (0.18, 0.46135), (0.5, 0.73536), (1.0, 1.0))


def _frame(h: int = 64, w: int = 80, centre: tuple[int, int] = (30, 50),
           meta: dict | None = None) -> RadianceImage:
    """A disc of radius 15 px at ``centre`` (row, col) whose radiance ramps 1..20 W m^-2 sr^-1
    from west to east."""
    v, u = np.mgrid[0:h, 0:w]
    mask = (v - centre[0]) ** 2 + (u - centre[1]) ** 2 <= 15**2
    L = np.where(mask, 1.0 + 19.0 * (u - centre[1] + 15) / 30.0, 0.0).astype(np.float32)
    geometry = {"index": 7, "range_m": 7.2345e7, "phase_angle_rad": math.radians(43.21)}
    return RadianceImage(L, L * 1e3, {"mask": mask.astype(np.float32)},
                         meta if meta is not None else {"geometry": geometry})


@pytest.mark.parametrize(("x", "s"), SRGB_REFERENCE)
def test_srgb_encoding_matches_the_standard(x, s):
    assert float(srgb_encode(x)) == pytest.approx(s, abs=5e-5)


def test_stretch_is_linear_from_zero_to_the_percentile_of_lit_pixels():
    img = _frame()
    grey, top = radiance_stretch(img.L)
    lit = img.L[img.L > 0]
    assert top == pytest.approx(np.percentile(lit, 99.9))
    # black is zero radiance; white is reached by at most 0.1 % (+1 px) of the lit pixels
    assert (grey[img.L == 0] == 0).all()
    assert np.count_nonzero(grey == 255) <= 0.001 * lit.size + 1
    # half of the top radiance shows as sRGB mid-grey: the screen's luminance is linear in L
    g, _ = radiance_stretch(np.array([[0.0, 0.5 * top, top]]), 100.0)
    assert g.tolist() == [[0, 188, 255]]
    # a frame with no lit pixel is black, not a division by zero
    z, ztop = radiance_stretch(np.zeros((4, 4)))
    assert ztop == 0.0 and not z.any()
    with pytest.raises(ConfigError, match="percentile"):
        radiance_stretch(img.L, 0.0)


def test_preview_png_holds_the_frame_pixel_for_pixel_and_is_labelled(tmp_path):
    from PIL import Image

    img = _frame()
    info = write_radiance_preview(img, tmp_path / "p.png")
    with Image.open(info.path) as im:
        assert im.mode == "L"
        a = np.asarray(im)
    assert a.shape == info.shape
    r0, c0 = info.origin
    grey, top = radiance_stretch(img.L)
    assert np.array_equal(a[r0:r0 + 64, c0:c0 + 80], grey)
    assert info.l_top == pytest.approx(top)
    assert info.caption == "frame 7 | range 72 345 km | phase 43.2 deg"
    assert a[:r0].max() > 128  # caption text drawn above the frame
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind


def test_write_previews_puts_a_png_next_to_each_exr(tmp_path):
    p = write_exr(_frame(), tmp_path / "frame_000007.exr")
    (info,) = write_previews([p])
    assert info.path == tmp_path / "frame_000007.png" and info.path.is_file()


def test_radiance_dn_figure_crops_every_panel_around_the_moon(tmp_path):
    import imageio.v3 as iio

    from starnav.preview import _moon_crop, plot_radiance_and_dn

    img = _frame(200, 240, centre=(100, 120))
    rows, cols = _moon_crop(img.L, 0.6)
    lit = np.argwhere(img.L > 0)
    # a square holding the whole disc (31 px) with 0.6 of its size free on each side
    assert rows.stop - rows.start == cols.stop - cols.start == math.ceil(31 * 2.2)
    assert rows.start <= lit[:, 0].min() - 18 and rows.stop >= lit[:, 0].max() + 1 + 18
    assert cols.start <= lit[:, 1].min() - 18 and cols.stop >= lit[:, 1].max() + 1 + 18
    # clipped at the frame's edge, never wider than the frame
    r2, c2 = _moon_crop(_frame(200, 240, centre=(10, 120)).L, 0.6)
    assert r2.start == 0 and c2.stop - c2.start == 69
    assert _moon_crop(np.zeros((8, 9)), 0.5) == (slice(0, 8), slice(0, 9))
    dn = np.clip(img.L * 300.0, 0, 4095).astype(np.uint16)
    p = plot_radiance_and_dn(img, [("1 ms", dn, 4095), ("2 ms", 2 * dn, 4095)],
                             tmp_path / "f.png")
    a = iio.imread(p)
    assert a.dtype == np.uint8 and a.shape[1] > 2.5 * a.shape[0]
