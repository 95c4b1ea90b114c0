"""Quick looks (starnav.quicklook): 8-bit, the frame's shape, the lit Moon bright and the sky
dark, annotated, atomic; and that ``render`` and ``dataset`` write one next to each frame."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from starnav import quicklook as Q
from starnav.quicklook import (
    QUICKLOOK_BAR_PX,
    QUICKLOOK_CAPTION_PX,
    asinh_stretch,
    quicklook_levels,
    write_dn_quicklook,
    write_quicklook,
)


def _moon_dn(h: int = 200, w: int = 240, offset: int = 20, seed: int = 3) -> tuple[
        np.ndarray, np.ndarray]:
    """A 12-bit DN frame: a sky at ``offset`` with noise and a lit disc of radius 30 px whose
    brightness falls from 4095 (saturated limb) to 150 DN at the terminator."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:h, 0:w]
    r = np.hypot(u - 150, v - 110)
    disc = r < 30
    dn = offset + rng.normal(0, 2.0, (h, w))
    shade = np.clip((u - 120) / 60.0, 0.0, 1.0)   # terminator on the left
    dn[disc] += 150 + 3900 * shade[disc]
    return np.clip(np.round(dn), 0, 4095).astype(np.uint16), disc


def _body(a: np.ndarray) -> np.ndarray:
    """Rows outside the caption band and the scale bar strip."""
    return a[QUICKLOOK_CAPTION_PX:-(QUICKLOOK_BAR_PX + QUICKLOOK_CAPTION_PX + 2)]


def test_dn_quicklook_is_8bit_frame_shaped_moon_bright_sky_dark(tmp_path):
    dn, disc = _moon_dn()
    p = tmp_path / "dn_quicklook.png"
    info = write_dn_quicklook(dn, p, index=7, exposure_time=1.5e-5, range_m=72_345e3,
                              phase_angle_rad=np.radians(43.2))
    im = Image.open(p)
    assert im.mode == "L" and im.size == (dn.shape[1], dn.shape[0])
    a = np.asarray(im)
    body, dbody = _body(a), _body(disc)
    lit = dbody & (_body(dn) > 2000)
    # the sky at the black level (median) maps to the bottom of the range, the lit disc high
    assert np.median(body[~dbody]) <= 10
    assert np.median(body[lit]) >= 200
    # the faint terminator (150 DN over a 4095 white) is lifted by the asinh stretch: a linear
    # stretch would give 255 * 150 / 4075 = 9; asinh with s = 0.05 gives ~ 100
    faint = dbody & (_body(dn) < 250)
    assert np.median(body[faint]) > 60
    assert info.black == pytest.approx(np.median(dn))
    sigma = 1.4826 * np.median(np.abs(dn - np.median(dn)))
    above = dn[dn > np.median(dn) + 5 * sigma].astype(float)
    assert info.white == pytest.approx(np.percentile(above, 99.5))
    assert 3900 < info.white <= 4095


def test_annotation_in_text_chunks_and_burnt_in(tmp_path):
    dn, _ = _moon_dn()
    p = tmp_path / "q.png"
    write_dn_quicklook(dn, p, index=7, exposure_time=1.5e-5, range_m=72_345e3,
                       phase_angle_rad=np.radians(43.2))
    im = Image.open(p)
    d = im.text["Description"]
    for part in ("frame 7", "exp 0.015 ms", "range 72 345 km", "phase 43.2 deg", "asinh",
                 "DN"):
        assert part in d
    assert im.text["starnav:unit"] == "DN"
    assert float(im.text["starnav:black"]) == pytest.approx(float(np.median(dn)))
    a = np.asarray(im)
    # the caption band: white text on black over the top-left rows of an otherwise dark sky
    band = a[:QUICKLOOK_CAPTION_PX, :150]
    assert np.count_nonzero(band > 128) > 30
    # the scale bar: a ramp from black to white along the bottom-left rows
    bar = a[-QUICKLOOK_BAR_PX:-1, 2:2 + min(dn.shape[1] // 3, 256)]
    assert bar[:, 0].max() == 0 and bar[:, -1].min() == 255
    assert np.all(np.diff(bar[0].astype(int)) >= 0)


def test_levels_ignore_the_sky_when_the_moon_is_tiny():
    """A 3x3 Moon in a 500 x 500 sky (0.004 % of the pixels): a percentile over all pixels would
    be the sky; the white level must be the Moon's."""
    a = np.full((500, 500), 30.0)
    a[100:103, 100:103] = 3000.0
    black, white = quicklook_levels(a)
    assert black == 30.0 and white == 3000.0
    g = asinh_stretch(a, black, white)
    assert g[101, 101] == 255 and g[0, 0] == 0


def test_asinh_stretch_closed_form():
    """255 asinh(x/s)/asinh(1/s) at x = 0.1 with s = 0.05: asinh(2)/asinh(20) = 0.3933."""
    g = asinh_stretch([0.0, 10.0, 100.0], 0.0, 100.0, softening=0.05)
    assert list(g) == [0, round(255 * np.arcsinh(2.0) / np.arcsinh(20.0)), 255]


def test_written_atomically(tmp_path, monkeypatch):
    """A failure while the PNG is being written leaves neither the PNG nor a temporary."""
    dn, _ = _moon_dn()

    def broken_save(self, fp, *a, **k):
        with open(fp, "wb") as fh:
            fh.write(b"\x89PNG half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Q.Image.Image, "save", broken_save)
    with pytest.raises(OSError):
        write_quicklook(dn, tmp_path / "q.png", "frame 0", unit="DN")
    assert list(tmp_path.iterdir()) == []


def test_bytes_are_deterministic(tmp_path):
    dn, _ = _moon_dn()
    a = write_quicklook(dn, tmp_path / "a.png", "frame 0", unit="DN").path.read_bytes()
    b = write_quicklook(dn, tmp_path / "b.png", "frame 0", unit="DN").path.read_bytes()
    assert a == b
