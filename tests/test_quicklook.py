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

    def broken_write(self, data):
        with open(self, "wb") as fh:
            fh.write(data[:100])
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Q.Path, "write_bytes", broken_write)
    with pytest.raises(OSError, match="No space left"):
        write_quicklook(dn, tmp_path / "q.png", "frame 0", unit="DN")
    assert list(tmp_path.iterdir()) == []


def test_bytes_are_deterministic(tmp_path):
    dn, _ = _moon_dn()
    a = write_quicklook(dn, tmp_path / "a.png", "frame 0", unit="DN").path.read_bytes()
    b = write_quicklook(dn, tmp_path / "b.png", "frame 0", unit="DN").path.read_bytes()
    assert a == b


# ------------------------------------------------- fast levels and stretch vs the plain formula
def _levels_reference(values, black=None):
    """:func:`quicklook_levels` as its docstring states it, with ``np.median`` and
    ``np.percentile`` on the whole frame converted to float64 (the slow reference)."""
    a = np.asarray(values, np.float64)
    b = float(np.median(a)) if black is None else float(black)
    sigma = 1.4826 * float(np.median(np.abs(a - b)))
    above = a[a > b + max(Q.QUICKLOOK_SKY_SIGMAS * sigma, 0.0)]
    if above.size == 0:
        return b, b + 1.0
    w = float(np.percentile(above, Q.QUICKLOOK_WHITE_PERCENTILE))
    return b, (w if w > b else float(above.max()))


def _stretch_reference(values, black, white, s=Q.QUICKLOOK_SOFTENING):
    """255 asinh(x / s) / asinh(1 / s) on every pixel."""
    x = np.clip((np.asarray(values, np.float64) - black) / (white - black), 0.0, 1.0)
    return np.round(np.clip(np.arcsinh(x / s) / np.arcsinh(1.0 / s), 0, 1) * 255).astype(
        np.uint8)


def _frames(seed: int = 11):
    """DN frames (odd and even pixel counts, saturated pixels, a given half-integer black) and
    radiance frames (float32, mostly or partly zero), as ``(values, black)``."""
    rng = np.random.default_rng(seed)
    out = [(_moon_dn()[0], None)]
    for i in range(30):
        shape = (int(rng.integers(1, 400)), int(rng.integers(1, 40)))
        dn = np.clip(rng.normal(100, rng.uniform(0.1, 30), shape), 0, 4095).astype(np.uint16)
        dn[rng.random(shape) < 0.01] = 4095
        out += [(dn, None), (dn, float(rng.integers(0, 200)) + 0.5 * (i % 2))]
        lit = rng.random(shape) < rng.uniform(0.0, 0.8)
        rad = np.where(lit, rng.exponential(1.0, shape), 0.0).astype(np.float32)
        out += [(rad, 0.0), (rad, None), (rng.normal(3, 1, shape), None)]
    return out


def test_levels_equal_the_median_reference_exactly():
    """The histogram medians of a 16-bit frame and the zero-count MAD of a radiance frame give
    the very numbers of np.median / np.percentile on the whole frame (a seeded comparison:
    equality, not a tolerance)."""
    for values, black in _frames():
        assert quicklook_levels(values, black=black) == _levels_reference(values, black)


def test_stretch_equals_the_formula_on_every_pixel():
    """The table look-up (integer frames) and the masked evaluation (float frames) give the
    formula's bytes on every pixel, the sky (at or below black) included."""
    for values, black in _frames(12):
        lo, hi = quicklook_levels(values, black=black)
        assert np.array_equal(asinh_stretch(values, lo, hi), _stretch_reference(values, lo, hi))
    big = np.random.default_rng(2).exponential(1.0, (200, 200)).astype(np.float32)
    big[:150] = 0.0
    assert np.array_equal(asinh_stretch(big, 0.0, 2.0), _stretch_reference(big, 0.0, 2.0))
