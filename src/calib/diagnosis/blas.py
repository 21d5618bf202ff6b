"""OpenBLAS limited to one thread while the diagnosis runs.

The diagnosis is thousands of small dense problems (<= 400 x 60); a multithreaded BLAS only adds
synchronisation. Measured on the 2-core machine, the diagnosis of the CI calibration session takes 0.8 s
single-threaded and 3.9 s with OpenBLAS's default threads. The thread count is set through the library's
own ``openblas_set_num_threads`` (found in the process's memory map), so it also works when numpy was
imported before and without an environment variable.
"""
from __future__ import annotations

import ctypes

_BLAS_FUNCS = (("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
               ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
               ("openblas_set_num_threads", "openblas_get_num_threads"),
               ("openblas_set_num_threads64_", "openblas_get_num_threads64_"))


def _blas_handles():
    """(set, get) thread-count functions of every OpenBLAS library mapped into this process."""
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
