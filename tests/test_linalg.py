"""starnav.linalg: LAPACK's kernels called directly give what numpy.linalg gives (regression
tests against NumPy's own wrappers: the same bits, the same errors)."""

from __future__ import annotations

import numpy as np
import pytest

from starnav.linalg import lstsq_vectors, solve, solve_vectors


def test_solves_are_numpys_bit_for_bit():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((16, 4, 4)) + 3.0 * np.eye(4)
    B = rng.standard_normal((16, 4, 5))
    assert np.array_equal(solve(A, B), np.linalg.solve(A, B))
    b = rng.standard_normal((16, 4))
    assert np.array_equal(solve_vectors(A, b), np.linalg.solve(A, b[..., None])[..., 0])
    assert np.array_equal(solve_vectors(A[0], b[0]), np.linalg.solve(A[0], b[0]))


def test_a_singular_matrix_raises_as_numpy_does():
    A = np.zeros((3, 2, 2))
    A[:, 0, 0] = A[:, 1, 1] = 1.0
    A[1] = 0.0   # one singular matrix in the stack
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.solve(A, np.ones((3, 2, 1)))
    with pytest.raises(np.linalg.LinAlgError):
        solve(A, np.ones((3, 2, 1)))
    with pytest.raises(np.linalg.LinAlgError):
        solve_vectors(A, np.ones((3, 2)))


def test_least_squares_are_numpys_set_by_set():
    rng = np.random.default_rng(1)
    A = rng.standard_normal((3, 16, 3))
    A[2, :, 2] = A[2, :, 0]   # rank 2
    b = rng.standard_normal((3, 16))
    x, rank = lstsq_vectors(A, b)
    for k in range(3):
        xk, _, rk, _ = np.linalg.lstsq(A[k], b[k], rcond=None)
        assert np.array_equal(x[k], xk) and rank[k] == rk
    assert list(rank) == [3, 3, 2]
    x0, r0 = lstsq_vectors(A[0], b[0])
    assert np.array_equal(x0, x[0]) and r0 == 3


def test_without_the_private_kernels_the_public_functions_give_the_same(monkeypatch):
    """A NumPy whose private kernels are missing or changed: the public wrappers serve, with
    the same results and errors."""
    import starnav.linalg as L

    rng = np.random.default_rng(2)
    A = rng.standard_normal((4, 3, 3)) + 3.0 * np.eye(3)
    b = rng.standard_normal((4, 3))
    Als = rng.standard_normal((2, 8, 3))
    bls = rng.standard_normal((2, 8))
    fast = (L.solve(A, b[..., None]), L.solve_vectors(A, b), L.lstsq_vectors(Als, bls))
    monkeypatch.setattr(L, "_gufuncs", None)
    assert np.array_equal(L.solve(A, b[..., None]), fast[0])
    assert np.array_equal(L.solve_vectors(A, b), fast[1])
    x, rank = L.lstsq_vectors(Als, bls)
    assert np.allclose(x, fast[2][0], rtol=1e-12) and np.array_equal(rank, fast[2][1])
    with pytest.raises(np.linalg.LinAlgError):
        L.solve_vectors(np.zeros((2, 2)), np.ones(2))
