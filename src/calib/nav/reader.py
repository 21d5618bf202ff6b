"""Streaming reader of ``calib-recording-1`` samples for long navigation runs: chunk-aligned, overlapped.

:func:`iter_raw_chunks` is :func:`calib.io.recording.iter_raw_chunks` (slices of a whole number of the file's chunks
along ``time``: every chunk read once, by one large read, straight into the output array) with this module's
default slice, the samples as stored (no netCDF scale_factor / add_offset applied, as before).

:func:`for_each_chunk` runs a function on every slice in a worker thread while the calling thread reads the
next slice, so reading from disk and navigating overlap (the navigation kernels are compiled without the
GIL). All netCDF calls stay in the calling thread: the netCDF-C/HDF5 library is not thread-safe, and a
reader thread would break any other netCDF use of the process during the run. The function must therefore
not use netCDF itself (the navigation and pre-integration kernels do not).

Memory stays flat: two slices are in memory at a time, the one being processed and the one being read (two
arrays of ``slice x 3`` float64 each: 50 MB at the default slice).
"""
from __future__ import annotations

import threading

from calib.io import recording

#: target number of samples per slice when the caller gives none (24 MB per float64 triad)
DEFAULT_SLICE = 1 << 20


def iter_raw_chunks(path, header: recording.Header | None = None, chunk: int | None = None, start: int = 0,
                    stop=None):
    """Yield ``(first_sample_index, accel, gyro)`` raw float64 arrays (n, 3) of ``[start, stop)`` in order.

    ``chunk``: target samples per slice (default :data:`DEFAULT_SLICE`), rounded to a whole number of the
    file's chunks. A file the library cannot read raises :class:`calib.io.recording.RecordingError`.
    """
    yield from recording.iter_raw_chunks(path, header, chunk or DEFAULT_SLICE, start, stop, auto_scale=False)


def for_each_chunk(path, fn, header: recording.Header | None = None, chunk: int | None = None, start: int = 0,
                   stop=None, progress=None, overlap: bool = True) -> None:
    """Call ``fn(first_sample_index, accel, gyro)`` on every slice of ``[start, stop)`` in order (the slices of
    :func:`iter_raw_chunks`), in a worker thread while this thread reads the next slice.

    ``fn`` must not use netCDF (see the module docstring); an exception it raises is raised here (after the
    slice being read). ``progress(samples_done_up_to)`` is called in this thread once ``fn`` has finished a
    slice. ``overlap=False`` runs everything in this thread (same calls, same order).
    """
    nc, bounds, read = recording.open_slices(path, header, chunk or DEFAULT_SLICE, start, stop, auto_scale=False)
    try:
        if not overlap or len(bounds) < 2:
            for i0, i1 in bounds:
                fn(i0, *read(i0, i1))
                if progress is not None:
                    progress(i1)
            return
        _overlapped(bounds, read, fn, progress)
    finally:
        nc.close()


class _Worker:
    """One call of ``fn`` in a thread; ``wait()`` joins it and re-raises its exception."""

    def __init__(self, fn, args):
        self.exc = None
        self.thread = threading.Thread(target=self._run, args=(fn, args), name="calib-nav-worker", daemon=True)
        self.thread.start()

    def _run(self, fn, args):
        try:
            fn(*args)
        except BaseException as exc:  # noqa: BLE001 - handed to the calling thread
            self.exc = exc

    def wait(self):
        self.thread.join()
        if self.exc is not None:
            exc, self.exc = self.exc, None
            raise exc


def _overlapped(bounds, read, fn, progress):
    pending, done_to = None, None
    try:
        for i0, i1 in bounds:
            acc, gyr = read(i0, i1)  # while the worker processes the previous slice
            if pending is not None:
                pending.wait()
                if progress is not None:
                    progress(done_to)
            pending, done_to = _Worker(fn, (i0, acc, gyr)), i1
            del acc, gyr
        pending.wait()
        pending = None
        if progress is not None:
            progress(done_to)
    finally:
        if pending is not None:  # interrupted or a read failed: let the running slice finish, then leave
            pending.thread.join()
