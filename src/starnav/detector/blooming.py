"""Full-well saturation and blooming, charge conserving except what leaves the array or drains.

1. Pixels above the full well keep it; their excess is split into a drained part and a
   spilled part (``spill_fraction``).
2. Each connected group of full pixels spills to its nearest non-full pixels, nearest shell
   first, the last shell in proportion to free capacity (symmetry kept); distance Euclidean
   (``isotropic``) or along the column (``column``); pixels split between groups by a Voronoi
   partition.
3. Charge past the detector's edge has left the array and is reported; the working canvas
   grows until the result does not depend on it.
4. ``drain``: the perfect anti-blooming drain, a clip at the full well.

Charge balance (tested): ``sum(in) = sum(out) + drained + left_array``.

Index
-----
:func:`bloom`, :class:`BloomResult`, :func:`bloom_drain`, :func:`bloom_isotropic`,
:func:`bloom_column`, :func:`register_blooming_mode`, :data:`BLOOMING_MODES`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from starnav.registry import Registry
from starnav.typing import Float32Array

logger = logging.getLogger(__name__)


#: Relative tolerance under which left-over spill charge is considered spent.
SPILL_TOL = 1e-12
#: Most merge/redistribution passes before the rest is declared lost (never reached in tests).
MAX_PASSES = 200


@dataclass(frozen=True)
class BloomResult:
    """Charge after saturation and blooming, and where the rest went.

    Attributes
    ----------
    charge : (H, W) float32
        Charge per pixel [e-], <= full well.
    drained : float
        Charge removed by the drain [e-].
    left_array : float
        Charge that spilled out of the array [e-].
    """

    charge: Float32Array
    drained: float
    left_array: float


BloomFunction = Callable[[Float32Array, float, float, int], BloomResult]

#: Blooming modes by name: ``f(charge, full_well, spill_fraction, max_margin) -> BloomResult``.
BLOOMING_MODES: Registry[BloomFunction] = Registry("blooming mode")


def register_blooming_mode(name: str) -> Callable[[BloomFunction], BloomFunction]:
    """Decorator registering a blooming mode under ``name``."""
    return BLOOMING_MODES.register(name)


def bloom(charge: Float32Array, full_well: float, mode: str = "isotropic",
          spill_fraction: float = 5e-4, max_margin: int = 1024) -> BloomResult:
    """Saturate ``charge`` [e-] at ``full_well`` [e-] and spill the excess with ``mode``.

    Parameters
    ----------
    charge : (H, W) float32
        Collected charge [e-].
    full_well : float
        Full-well capacity [e-].
    mode : str
        Name in :data:`BLOOMING_MODES`.
    spill_fraction : float
        Fraction of the excess that spills (the rest drains) [-].
    max_margin : int
        Virtual pixels followed outside the array [px].
    """
    fn = BLOOMING_MODES.get(mode)
    return fn(charge, float(full_well), float(spill_fraction), int(max_margin))


@register_blooming_mode("drain")
def bloom_drain(charge: Float32Array, full_well: float, spill_fraction: float = 0.0,
                max_margin: int = 0) -> BloomResult:
    """Perfect anti-blooming drain: clip at ``full_well``; all excess is drained."""
    over = charge > full_well
    if not over.any():
        return BloomResult(charge.copy(), 0.0, 0.0)
    drained = float((charge[over].astype(np.float64) - full_well).sum())
    return BloomResult(np.minimum(charge, np.float32(full_well)), drained, 0.0)


@register_blooming_mode("isotropic")
def bloom_isotropic(charge: Float32Array, full_well: float, spill_fraction: float,
                    max_margin: int = 1024) -> BloomResult:
    """Spill to the nearest non-full pixels in every direction (Euclidean distance)."""
    return _spill(charge, full_well, spill_fraction, max_margin, column=False)


@register_blooming_mode("column")
def bloom_column(charge: Float32Array, full_well: float, spill_fraction: float,
                 max_margin: int = 1024) -> BloomResult:
    """Bleed up and down the column (distance along the column only)."""
    return _spill(charge, full_well, spill_fraction, max_margin, column=True)


# --------------------------------------------------------------------------- implementation
class _Canvas:
    """Charge on a window of the array extended with virtual pixels outside it."""

    def __init__(self, q: NDArray[np.float64], r0: int, r1: int, c0: int, c1: int) -> None:
        H, W = q.shape
        self.H, self.W = H, W
        self.r0, self.r1, self.c0, self.c1 = r0, r1, c0, c1
        self.Q = np.zeros((r1 - r0, c1 - c0))
        self.E = np.zeros_like(self.Q)
        rr = np.arange(r0, r1)
        cc = np.arange(c0, c1)
        self.inarr = ((rr >= 0) & (rr < H))[:, None] & ((cc >= 0) & (cc < W))[None, :]
        a0, a1, b0, b1 = max(r0, 0), min(r1, H), max(c0, 0), min(c1, W)
        self.Q[a0 - r0 : a1 - r0, b0 - c0 : b1 - c0] = q[a0:a1, b0:b1]

    def grown(self, q: NDArray[np.float64], r0: int, r1: int, c0: int, c1: int) -> _Canvas:
        """A larger canvas holding this one's state (``q`` supplies the new in-array pixels)."""
        new = _Canvas(q, r0, r1, c0, c1)
        sl = (slice(self.r0 - r0, self.r1 - r0), slice(self.c0 - c0, self.c1 - c0))
        new.Q[sl] = self.Q
        new.E[sl] = self.E
        return new

    def write_back(self, q: NDArray[np.float64]) -> float:
        """Copy the in-array part into ``q``; return the charge on virtual pixels."""
        a0, a1, b0, b1 = max(self.r0, 0), min(self.r1, self.H), max(self.c0, 0), min(self.c1,
                                                                                     self.W)
        q[a0:a1, b0:b1] = self.Q[a0 - self.r0 : a1 - self.r0, b0 - self.c0 : b1 - self.c0]
        return float(self.Q[~self.inarr].sum())


def _margin_isotropic(bh: int, bw: int, n_pixels: float) -> int:
    a = 2.0 * n_pixels + 16.0
    return int(math.ceil((-(bh + bw) + math.sqrt((bh + bw) ** 2 + 4.0 * a)) / 4.0)) + 2


def _column_distance(src: NDArray[np.bool_]) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Distance along the column to the nearest ``src`` pixel and that pixel's row."""
    h = src.shape[0]
    rows = np.arange(h)[:, None]
    big = 10 * h + 10
    above = np.where(src, rows, -big)
    np.maximum.accumulate(above, axis=0, out=above)
    below = np.where(src, rows, 2 * big)
    below = np.minimum.accumulate(below[::-1], axis=0)[::-1]
    da, db = rows - above, below - rows
    use_above = da <= db
    dist = np.where(use_above, da, db).astype(np.float64)
    src_row = np.where(use_above, above, below)
    dist[dist >= big] = np.inf
    return dist, np.clip(src_row, 0, h - 1)


def _fill_pass(cv: _Canvas, F: float, column: bool) -> tuple[float, bool]:
    """One distance-ordered fill of every group's excess. Returns (charge placed, touched the
    canvas border)."""
    from scipy import ndimage

    Q, E = cv.Q, cv.E
    full = Q >= F * (1.0 - 1e-12)
    structure = (np.array([[0, 1, 0], [0, 1, 0], [0, 1, 0]], bool) if column
                 else ndimage.generate_binary_structure(2, 1))
    lab, n = ndimage.label(full, structure=structure)
    has_e = E > 0
    Ec = np.bincount(lab[has_e], weights=E[has_e], minlength=n + 1)
    Ec[0] = 0.0
    srcfull = full & (Ec[lab] > 0)
    if column:
        dist, src_row = _column_distance(srcfull)
        owner = lab[src_row, np.arange(Q.shape[1])[None, :]]
    else:
        dist, (iv, iu) = ndimage.distance_transform_edt(~srcfull, return_indices=True)
        owner = lab[iv, iu]
    cand = ~full & np.isfinite(dist) & (Ec[owner] > 0)
    idx = np.flatnonzero(cand)
    if idx.size == 0:
        return 0.0, False
    own = owner.ravel()[idx]
    d = dist.ravel()[idx]
    cap = F - Q.ravel()[idx]
    order = np.lexsort((d, own))
    idx, own, d, cap = idx[order], own[order], d[order], cap[order]
    # shells: runs of equal (owner, distance)
    new_shell = np.ones(idx.size, bool)
    new_shell[1:] = (own[1:] != own[:-1]) | (d[1:] != d[:-1])
    starts = np.flatnonzero(new_shell)
    shell_cap = np.add.reduceat(cap, starts)
    shell_own = own[starts]
    cum = np.cumsum(shell_cap)
    # cumulative capacity before each shell, restarted for every owner
    new_owner = np.ones(starts.size, bool)
    new_owner[1:] = shell_own[1:] != shell_own[:-1]
    owner_first = np.flatnonzero(new_owner)
    base = np.repeat(cum[owner_first] - shell_cap[owner_first],
                     np.diff(np.append(owner_first, starts.size)))
    before = cum - shell_cap - base
    frac = np.clip((Ec[shell_own] - before) / shell_cap, 0.0, 1.0)
    fill = cap * np.repeat(frac, np.diff(np.append(starts, idx.size)))
    placed_by = np.bincount(own, weights=fill, minlength=n + 1)
    Q.ravel()[idx] += fill
    # left-over of each group goes back onto one of its pixels for the next pass
    E[:] = 0.0
    left = Ec - placed_by
    left[left < SPILL_TOL * max(Ec.max(), 1.0)] = 0.0
    for g in np.flatnonzero(left > 0):
        r, c = np.argwhere(lab == g)[0]
        E[r, c] = left[g]
    touched = fill > 0
    rr, cc = np.divmod(idx[touched], Q.shape[1])
    border = bool(rr.size and (rr.min() == 0 or rr.max() == Q.shape[0] - 1 or
                               (not column and (cc.min() == 0 or cc.max() == Q.shape[1] - 1))))
    return float(fill.sum()), border


def _spill(charge: Float32Array, F: float, s: float, max_margin: int,
           column: bool) -> BloomResult:
    over = charge > F
    if not over.any():
        return BloomResult(charge.copy(), 0.0, 0.0)
    H, W = charge.shape
    q = charge.astype(np.float64)
    excess = np.where(over, q - F, 0.0)
    q[over] = F
    drained = float(excess.sum() * (1.0 - s))
    spill = excess * s
    total_spill = float(spill.sum())
    if total_spill <= 0.0:
        return BloomResult(q.astype(np.float32), drained, 0.0)
    rows = np.flatnonzero(over.any(axis=1))
    cols = np.flatnonzero(over.any(axis=0))
    br0, br1, bc0, bc1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    lim = (-max_margin, H + max_margin, -max_margin, W + max_margin)
    if column:
        m = int(math.ceil(2.0 * spill.sum(axis=0).max() / F)) + 2
    else:
        m = _margin_isotropic(br1 - br0, bc1 - bc0, total_spill / F)

    def make_box(m: int) -> tuple[int, int, int, int]:
        if column:
            return (max(br0 - m, lim[0]), min(br1 + m, lim[1]), bc0, bc1)
        return (max(br0 - m, lim[0]), min(br1 + m, lim[1]), max(bc0 - m, lim[2]),
                min(bc1 + m, lim[3]))

    box = make_box(m)
    cv = _Canvas(q, *box)
    cv.E[br0 - box[0] : br1 - box[0], bc0 - box[2] : bc1 - box[2]] = spill[br0:br1, bc0:bc1]
    lost = 0.0
    for _ in range(MAX_PASSES):
        if not (cv.E > 0).any():
            break
        saved_Q, saved_E = cv.Q.copy(), cv.E.copy()
        placed, border = _fill_pass(cv, F, column)
        if border:
            m = 2 * m + 8
            new_box = make_box(m)
            if new_box != box:  # redo this pass on a larger canvas
                cv.Q, cv.E = saved_Q, saved_E
                box = new_box
                cv = cv.grown(q, *box)
                continue
        if placed <= SPILL_TOL * total_spill:
            lost = float(cv.E.sum())
            logger.warning("blooming: %.3g e- could not be placed within %d px of the array; "
                           "counted as lost", lost, max_margin)
            cv.E[:] = 0.0
            break
    else:  # pragma: no cover - guarded by MAX_PASSES
        lost = float(cv.E.sum())
    left = cv.write_back(q) + lost
    return BloomResult(q.astype(np.float32), drained, left)
