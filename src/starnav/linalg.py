"""Small dense solves for the per-frame chain, without NumPy's per-call checks.

:func:`solve` and :func:`solve_vectors` call the LAPACK ``gesv`` kernel behind
:func:`numpy.linalg.solve` directly (the same kernel, so the same bits): on the 3x3 and
4x4 systems the navigation chain solves many times a frame, the wrapper's argument checks
and type dispatch cost more than the solve. Float64 inputs only; a singular matrix raises
:class:`numpy.linalg.LinAlgError` as :func:`numpy.linalg.solve` does.

Index
-----
:func:`solve`, :func:`solve_vectors`, :func:`lstsq_vectors`.
"""

from __future__ import annotations

import numpy as np
from numpy.linalg import LinAlgError

from starnav.typing import FloatArray

try:   # the gufuncs numpy.linalg.solve wraps (a private module of NumPy)
    from numpy.linalg import _umath_linalg as _gufuncs
except ImportError:   # pragma: no cover - a NumPy without them: the public wrapper
    _gufuncs = None


def _gufuncs_agree() -> bool:
    """The private kernels are called as this NumPy's public functions call them and give
    their results on a small system (else, e.g. after a NumPy upgrade changed their
    signatures, the public functions are used)."""
    A = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]])
    b = np.array([1.0, -2.0, 0.5])
    try:
        return bool(
            np.array_equal(_gufuncs.solve(A, b[:, None], signature="dd->d"),
                           np.linalg.solve(A, b[:, None]))
            and np.array_equal(_gufuncs.solve1(A, b, signature="dd->d"),
                               np.linalg.solve(A, b))
            and np.allclose(_gufuncs.lstsq(A, b[:, None], np.finfo(float).eps * 3,
                                           signature="ddd->ddid")[0][:, 0],
                            np.linalg.lstsq(A, b, rcond=None)[0], rtol=1e-12, atol=0))
    except Exception:   # noqa: BLE001 - any failure means: do not use them
        return False


if _gufuncs is not None and not _gufuncs_agree():   # pragma: no cover
    _gufuncs = None


def _singular(err: str, flag: int) -> None:
    raise LinAlgError("Singular matrix")


def solve(A: FloatArray, b: FloatArray) -> FloatArray:
    """``A x = b`` for float64 ``A`` ``(..., n, n)`` and ``b`` ``(..., n, m)``: what
    ``np.linalg.solve(A, b)`` returns (``b`` a stack of matrices)."""
    if _gufuncs is None:   # pragma: no cover
        return np.linalg.solve(A, b)
    with np.errstate(call=_singular, invalid="call", over="ignore", divide="ignore",
                     under="ignore"):
        return _gufuncs.solve(A, b, signature="dd->d")


def solve_vectors(A: FloatArray, b: FloatArray) -> FloatArray:
    """``A x = b`` for float64 ``A`` ``(..., n, n)`` and ``b`` ``(..., n)``, one vector per
    matrix: ``np.linalg.solve(A, b[..., None])[..., 0]``."""
    if _gufuncs is None:   # pragma: no cover
        return np.linalg.solve(A, b[..., None])[..., 0]
    with np.errstate(call=_singular, invalid="call", over="ignore", divide="ignore",
                     under="ignore"):
        return _gufuncs.solve1(A, b, signature="dd->d")


def _no_convergence(err: str, flag: int) -> None:
    raise LinAlgError("SVD did not converge in Linear Least Squares")


def lstsq_vectors(A: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Least-squares ``A x = b`` for float64 ``A`` ``(..., m, n)`` and ``b`` ``(..., m)``,
    a stack solved in one call: what ``np.linalg.lstsq(A_i, b_i, rcond=None)`` gives for
    each, ``(x (..., n), rank (...))``."""
    m, n = A.shape[-2:]
    if _gufuncs is None or m == 0:   # pragma: no cover
        out = [np.linalg.lstsq(a, v, rcond=None) for a, v in
               zip(A.reshape(-1, m, n), b.reshape(-1, m), strict=True)]
        return (np.array([o[0] for o in out]).reshape(A.shape[:-2] + (n,)),
                np.array([o[2] for o in out]).reshape(A.shape[:-2]))
    with np.errstate(call=_no_convergence, invalid="call", over="ignore", divide="ignore",
                     under="ignore"):
        x, _, rank, _ = _gufuncs.lstsq(A, b[..., None], np.finfo(float).eps * max(n, m),
                                       signature="ddd->ddid")
    return x[..., 0], rank
