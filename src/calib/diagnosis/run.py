"""Running the diagnosis on a recording file or an in-memory dataset: the one entry point :func:`diagnose`."""
from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path

import numpy as np

from calib.diagnosis.analysis import analyse
from calib.diagnosis.blas import single_thread_blas
from calib.diagnosis.geometry import DiagnosisInputError
from calib.diagnosis.norm import setup_norm_problem
from calib.diagnosis.problem import settings_of
from calib.diagnosis.report import build_report, inconclusive_report, report_markdown
from calib.diagnosis.vector import setup_problem
from calib.io import recording
from calib.io.atomic import output_set, write_json as write_json_atomic, write_text as write_text_atomic
from calib.io.recording import RecordingError
from calib.signal import detect
from calib.signal.segments import SegmentError


def diagnose(recording_or_dataset, settings=None, *, out_dir=None, path: str = "", intervals=None,
             intervals_source: str = "", library_from=None) -> dict:
    """Diagnose a recording: a ``calib-recording-1`` file (path) or an in-memory dataset; returns the report.

    ``settings``: overrides of :data:`calib.diagnosis.DEFAULT_SETTINGS`. ``out_dir``: where ``report.json``,
    ``report.md`` and the figures go (None: nothing is written). For a file: ``intervals`` / ``intervals_source``
    as in :func:`diagnose_recording`. For a dataset: ``path`` names it in the report and ``library_from`` is a
    :class:`calib.diagnosis.Problem` on the same geometry whose library is reused (:func:`diagnose_dataset`).
    """
    if isinstance(recording_or_dataset, (str, os.PathLike)):
        return diagnose_recording(recording_or_dataset, out_dir, settings, intervals=intervals,
                                  intervals_source=intervals_source)
    rep, _ = diagnose_dataset(recording_or_dataset, out_dir, settings, path=path, library_from=library_from)
    return rep


def diagnose_dataset(ds, out_dir=None, settings=None, *, path="", library_from=None, geometry_from=None):
    """Diagnose an in-memory recording. Returns (report dict, Problem or None). Writes files when
    ``out_dir`` is given. ``library_from`` / ``geometry_from``: a previous Problem on the same geometry whose
    library / geometry is reused (:func:`calib.diagnosis.vector.setup_problem`; a norm recording reuses the
    geometry alone, :func:`calib.diagnosis.norm.setup_norm_problem`)."""
    st = settings_of(settings)
    t0 = time.perf_counter()
    # the figures and the two reports appear together or not at all (an interruption between them left figures
    # without their report, or beside an earlier run's)
    with output_set() if out_dir is not None else contextlib.nullcontext():
        with single_thread_blas():
            rep, prob = _diagnose_dataset(ds, out_dir, st, path, library_from, geometry_from)
        rep["elapsed_s"] = time.perf_counter() - t0
        if ds.attrs.get("segments_from"):
            rep["segments_from"] = str(ds.attrs["segments_from"])
        if out_dir is not None:
            write_report(rep, out_dir)
    return rep, prob


def _diagnose_dataset(ds, out_dir, st, path, library_from, geometry_from=None):
    prob = None
    try:
        if "nominal_attitude" in ds or (library_from is not None and library_from.kind == "vector"):
            prob = setup_problem(ds, st, library_from=library_from, geometry_from=geometry_from)
        else:
            prob = setup_norm_problem(ds, st, geometry_from=geometry_from)
        rank = np.linalg.matrix_rank(prob.whiten(prob.X0))
        if rank < prob.X0.shape[1]:
            raise DiagnosisInputError(f"the base calibration failed: its design has rank {rank} of "
                                      f"{prob.X0.shape[1]} (the positions do not determine every parameter)",
                                      "add static positions that point each axis up and down")
        res = analyse(prob)
        prob.last_fits = res["_fits"]
        if not np.isfinite(res["goodness_of_fit"]["before"]["chi2"]):
            raise DiagnosisInputError("the base calibration failed: non-finite chi-square")
        rep = build_report(prob, res, path, st, figures_dir=out_dir)
    except DiagnosisInputError as exc:
        rep = inconclusive_report(path, st, exc.reason, exc.fix)
    except (RecordingError, SegmentError) as exc:
        rep = inconclusive_report(path, st, str(exc))
    except (np.linalg.LinAlgError, FloatingPointError) as exc:
        rep = inconclusive_report(path, st, f"the base calibration failed numerically ({exc})",
                                  "check the recording for dead channels or segments with the same attitude")
    return rep, prob


def diagnose_recording(path, out_dir, settings=None, intervals=None, intervals_source: str = "",
                       name: str | None = None, return_problem: bool = False):
    """``calib diagnose RECORDING.nc --out DIR``: writes DIR/report.json, DIR/report.md and figures.

    Works on any ``calib-recording-1`` file with a segment table (synthetic or imported; an imported
    recording without one gets the static ``intervals`` given -- (m, 2) [start, stop) samples, e.g. those the
    field calibration used -- or else static segments from :func:`calib.signal.detect.detect_in_recording`). Bad input
    (unreadable file, too short, too few segments, failed calibration, no noise estimate) gives a report
    with verdict ``inconclusive`` and the reason -- never a finding. ``out_dir`` None: nothing is written.
    ``name``: what the report calls the recording (default: ``path``; e.g. for a temporary file, whose path would
    make the report differ from run to run). ``return_problem``: return ``(report, Problem or None)``, the set-up
    whose geometry other recordings of the same template may reuse (``diagnose_dataset(geometry_from=...)``).
    """
    st = settings_of(settings)
    ds, refusal = load_for_diagnosis(path, st, intervals, intervals_source)
    if refusal is not None:
        if name is not None:
            refusal["recording"] = str(name)
        if out_dir is not None:
            write_report(refusal, out_dir)
        return (refusal, None) if return_problem else refusal
    rep, prob = diagnose_dataset(ds, out_dir, st, path=path if name is None else name)
    return (rep, prob) if return_problem else rep


def load_for_diagnosis(path, settings=None, intervals=None, intervals_source: str = "", *, dataset: bool = False):
    """The recording at ``path`` as the diagnosis works on it: ``(dataset, None)`` with a segment table (the file's,
    the static ``intervals`` given, or static detection), or ``(None, inconclusive report)`` naming why not.

    The recording comes as :func:`calib.io.recording.load_arrays` reads it (numpy arrays: all the diagnosis reads,
    without importing xarray), or with ``dataset=True`` -- and whenever a segment table has to be added -- as an
    ``xarray.Dataset`` (:func:`calib.io.recording.load`; e.g. to make new recordings from it)."""
    st = settings_of(settings)
    try:
        ds = recording.load(path) if dataset else recording.load_arrays(path)
        if "segment_index" not in ds and isinstance(ds, recording.RecordingArrays):   # a table is added to a dataset
            ds = recording.load(path, validate_all=False)   # (checked by load_arrays just now)
    except (RecordingError, OSError, ValueError) as exc:
        return None, inconclusive_report(path, st, f"cannot read the recording: {exc}",
                                         "give a valid calib-recording-1 file")
    segments_from = "the recording's segment table"
    if "segment_index" not in ds:
        try:
            if intervals is not None:
                segments_from = (f"the {len(np.asarray(intervals).reshape(-1, 2))} static intervals of "
                                 f"{intervals_source or 'the caller'}")
                ds = detect.add_segment_table(ds, np.asarray(intervals, dtype=np.int64).reshape(-1, 2))
                ds["segment_index"].attrs["intervals_from"] = intervals_source or "given"
            else:
                ds = detect.add_segment_table(ds, detect.detect_in_recording(ds))
                segments_from = "static detection of the diagnosis (calib.signal.detect; give --fieldcal to use " \
                                "the intervals of a field calibration)"
        except Exception as exc:  # noqa: BLE001 - any detection failure is an inconclusive input
            return None, inconclusive_report(path, st, f"no segment table and static detection failed: {exc}",
                                             "add a segment table (segment_index, segment_kind)")
    ds.attrs["segments_from"] = segments_from
    return ds, None


def write_report(rep: dict, out_dir) -> None:
    """``out_dir/report.json`` and ``report.md`` of ``rep``, one output set (the wall time stays out of the file, so
    that the same input gives the same report)."""
    out_dir = Path(out_dir)
    with output_set():
        write_json_atomic({k: v for k, v in rep.items() if k != "elapsed_s"}, out_dir / "report.json")
        write_text_atomic(out_dir / "report.md", report_markdown(rep))
