"""OpenBLAS limited to one thread while the diagnosis runs, and the LAPACK calls of its small fits.

The diagnosis is thousands of small dense problems (<= 400 x 60); a multithreaded BLAS only adds
synchronisation. Measured on the 2-core machine, the diagnosis of the CI calibration session takes 0.8 s
single-threaded and 3.9 s with OpenBLAS's default threads (re-measured after the speed-up of issue #16: one
seed of the Liu 2021 lever-arm session 0.41 s single-threaded, 0.94 s to 34 s with the default threads while
another job shares the cores). The thread count is set through the library's own ``openblas_set_num_threads``
(found in the process's memory map), so it also works when numpy was imported before and without an environment
variable.

:func:`solve_tri` and :func:`pivoted_qr` make the LAPACK calls of ``scipy.linalg.solve_triangular`` and
``scipy.linalg.qr(..., pivoting=True)`` with the same arguments -- the same numbers to the bit -- without their
per-call validation and workspace queries, which cost as much as the arithmetic on these sizes.
"""
from __future__ import annotations

import ctypes
import os

import numpy as np
from scipy.linalg import get_lapack_funcs

_BLAS_FUNCS = (("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
               ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
               ("openblas_set_num_threads", "openblas_get_num_threads"),
               ("openblas_set_num_threads64_", "openblas_get_num_threads64_"))


_HANDLES: dict = {}   # per process id (a forked worker maps the same libraries): reading the map costs ~7 ms


def _blas_handles():
    """(set, get) thread-count functions of every OpenBLAS library mapped into this process (looked up once per
    process: the libraries are mapped when numpy and scipy are imported, before the first diagnosis)."""
    pid = os.getpid()
    if pid not in _HANDLES:
        _HANDLES.clear()
        _HANDLES[pid] = _find_blas_handles()
    return _HANDLES[pid]


def _find_blas_handles():
    out = []
    try:
        with open("/proc/self/maps") as fh:
            paths = {ln.split()[-1] for ln in fh if "openblas" in ln.lower() and ln.split()[-1].startswith("/")}
    except OSError:
        return out
    for p in sorted(paths):
        try:
            lib = ctypes.CDLL(p)
        except OSError:
            continue
        for set_name, get_name in _BLAS_FUNCS:
            if hasattr(lib, set_name) and hasattr(lib, get_name):
                out.append((getattr(lib, set_name), getattr(lib, get_name)))
                break
    return out


class single_thread_blas:
    """Context manager: OpenBLAS (numpy's and scipy's) limited to one thread inside, restored after."""

    def __enter__(self):
        self._h = _blas_handles()
        self._old = []
        for set_f, get_f in self._h:
            try:
                self._old.append(int(get_f()))
                set_f(1)
            except Exception:  # noqa: BLE001 - a BLAS without the call simply keeps its threads
                self._old.append(None)
        return self

    def __exit__(self, *exc):
        for (set_f, _), old in zip(self._h, self._old):
            if old:
                set_f(old)
        return False


_TRTRS, _GEQP3, _ORGQR = get_lapack_funcs(("trtrs", "geqp3", "orgqr"), (np.zeros((1, 1)),))
_LWORK: dict = {}   # optimal LAPACK workspace per (routine, shape): a function of the shape only


def _lwork(name, f, shape, *args):
    """The workspace size LAPACK's query returns for routine ``f`` on arrays of ``shape`` (cached)."""
    key = (name, shape)
    if key not in _LWORK:
        _LWORK[key] = int(f(*args, lwork=-1)[-2][0].real)
    return _LWORK[key]


def pivoted_qr(A):
    """Economic QR with column pivoting of a float64 (M, N) array, M >= N: ``(Q, R, piv)`` as
    ``scipy.linalg.qr(A, mode="economic", pivoting=True, check_finite=False)`` returns them -- the same LAPACK
    calls (geqp3, orgqr) with the same workspace (so the same numbers to the bit), the workspace queries made once
    per shape instead of at every call (the fits of the diagnosis factorise thousands of small designs)."""
    M, N = A.shape
    if A.size == 0 or M < N:
        from scipy.linalg import qr
        return qr(A, mode="economic", pivoting=True, check_finite=False)
    qr_, jpvt, tau, _, info = _GEQP3(A, lwork=_lwork("geqp3", _GEQP3, (M, N), A))
    if info < 0:
        raise ValueError(f"illegal value in {-info}th argument of internal geqp3")
    jpvt -= 1
    R = np.triu(qr_[:N, :])
    Q, _, info = _ORGQR(qr_, tau, lwork=_lwork("orgqr", _ORGQR, (M, N), qr_, tau), overwrite_a=1)
    if info < 0:
        raise ValueError(f"illegal value in {-info}th argument of internal orgqr")
    return Q, R, jpvt


def solve_tri(T, B, lower: bool = True):
    """``T^-1 B`` for a triangular ``T`` (float64, no check for finite values): the LAPACK call
    ``scipy.linalg.solve_triangular(T, B, lower=lower, check_finite=False)`` makes, with the same arguments (so the
    same result to the bit), without its per-call validation -- the whitening and the fits of the diagnosis solve
    tens of thousands of small triangular systems."""
    if B.size == 0:
        return np.empty_like(B, dtype=float)
    if T.flags.f_contiguous:
        x, info = _TRTRS(T, B, lower=int(lower), trans=0)
    else:   # trtrs expects Fortran order: the transposed system, as scipy solves it
        x, info = _TRTRS(T.T, B, lower=int(not lower), trans=1)
    if info > 0:
        raise np.linalg.LinAlgError(f"singular matrix: resolution failed at diagonal {info - 1}")
    if info < 0:
        raise ValueError(f"illegal value in {-info}-th argument of internal trtrs")
    return x


def solve_lower(L, B):
    """``L^-1 B`` for a lower-triangular ``L`` (:func:`solve_tri`)."""
    return solve_tri(L, B, lower=True)
