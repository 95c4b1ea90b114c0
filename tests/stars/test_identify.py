"""Lost-in-space identification's candidate triangles (issue 18: the inner loops vectorised)
against the definition written as nested loops, and the hypothesis cap of the count rule."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.stars.identify import (
    IdentifyOptions,
    _candidate_triangles,
    identify_lost_in_space,
)


def _brute_force(aij, bij, aik, bik, dirs, ajk, tol_jk, sense):
    """Module step 2 as written in words: for each catalogue star ``si`` of side ``ij`` that
    is also one of side ``ik`` (ascending), each ``sj`` paired with it in ``ij`` and each
    ``sk`` paired with it in ``ik`` (in table order): distinct, third side within the
    tolerance, same sense."""
    out = []
    for si in sorted(set(aij.tolist()) & set(aik.tolist())):
        for sj in bij[aij == si]:
            for sk in bik[aik == si]:
                if sj == sk:
                    continue
                dj, dk, di = dirs[sj], dirs[sk], dirs[si]
                if abs(math.acos(min(1.0, float(dj @ dk))) - ajk) > tol_jk:
                    continue
                if float(di @ np.cross(dj, dk)) * sense <= 0:
                    continue
                out.append((int(si), int(sj), int(sk)))
    return out


@pytest.mark.parametrize("seed", range(6))
def test_candidate_triangles_equal_the_nested_loop_definition(seed):
    rng = np.random.default_rng(seed)
    n_star = 40
    dirs = rng.normal(size=(n_star, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    # two sides' candidate pairs as a pair table gives them: distinct stars, each pair once,
    # in random order, several partners per star of i (a first star among 12)
    pairs = np.array([(a, b) for a in range(12) for b in range(n_star) if a != b], np.int32)
    ij = pairs[rng.choice(len(pairs), 150, replace=False)]
    ik = pairs[rng.choice(len(pairs), 120, replace=False)]
    aij, bij, aik, bik = ij[:, 0], ij[:, 1], ik[:, 0], ik[:, 1]
    for ajk, tol, sense in ((1.0, 0.3, 1.0), (0.5, 0.2, -1.0), (2.0, 1.0, 1.0)):
        got = list(zip(*(a.tolist() for a in _candidate_triangles(
            aij, bij, aik, bik, dirs, ajk, tol, sense)), strict=True))
        want = _brute_force(aij, bij, aik, bik, dirs, ajk, tol, sense)
        assert want, "the case must have candidates"
        assert got == want


def test_no_common_star_gives_no_candidate():
    dirs = np.eye(3)
    si, sj, sk = _candidate_triangles(np.array([0], np.int32), np.array([1], np.int32),
                                      np.array([1], np.int32), np.array([2], np.int32),
                                      dirs, 1.0, 1.0, 1.0)
    assert si.size == sj.size == sk.size == 0


def test_hypotheses_never_exceed_the_cap_of_the_count_rule():
    """A field of random 'stars' that match nothing: the search stops at ``max_hypotheses``
    exactly (the Poisson bound of step 3 counts that many trials; the loops before issue 18
    could pass it within a triangle)."""
    rng = np.random.default_rng(3)
    b = rng.normal(size=(12, 3)) * np.array([0.15, 0.15, 1.0]) + np.array([0.0, 0.0, 4.0])
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    sig = np.full(12, 2e-4)
    for cap in (7, 40):
        ident = identify_lost_in_space(b, sig, None, 2016.0, math.radians(29.0),
                                       options=IdentifyOptions(max_hypotheses=cap))
        assert not ident.ok
        assert ident.hypotheses == cap, (ident.hypotheses, ident.reason)
