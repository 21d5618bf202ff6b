"""The memory of files already checked by :func:`calib.io.validation.validate` within one command.

A command that checks its inputs up front and then loads them (``calib diagnose``: the recording and the noise
record) reads each file's samples once: inside :func:`reuse_validation` a file is named by :func:`identity`
(path, device, inode, size, modification and change times), and a later check of the same, unchanged file returns
the header of the first. Outside the block nothing is remembered and every check reads the file in full.
"""
from __future__ import annotations

import contextlib
import dataclasses
import os
from pathlib import Path

from calib.io.header import Header

#: files that passed the check while :func:`reuse_validation` is active: identity -> Header (None: inactive)
_VALIDATED: dict | None = None


def identity(path):
    """What names one unchanged file: resolved path, device, inode, size, modification and change times
    (None when the file cannot be looked at; the check then says why)."""
    try:
        st = os.stat(path)
        return (str(Path(path).resolve()), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
    except (OSError, ValueError):
        return None


@contextlib.contextmanager
def reuse_validation():
    """Within the block, :func:`calib.io.validation.validate` checks each file once: a later call on the same,
    unchanged file (same inode, size, modification and change times) returns the header of the first check
    instead of reading every sample again. For one command that checks its inputs up front and then loads them
    (``calib diagnose``: the recording and the noise record); outside the block every call checks the file in
    full. Nests."""
    global _VALIDATED
    outer = _VALIDATED
    if outer is None:
        _VALIDATED = {}
    try:
        yield
    finally:
        if outer is None:
            _VALIDATED = None


def active() -> bool:
    """Whether a :func:`reuse_validation` block is active (a file's :func:`identity` is then worth taking)."""
    return _VALIDATED is not None


def recalled(key) -> Header | None:
    """A copy of the header remembered for the file of identity ``key``; None when the file was not checked
    within the active block (or no block is active, or ``key`` is None)."""
    if _VALIDATED is None or key is None or key not in _VALIDATED:
        return None
    h = _VALIDATED[key]
    return dataclasses.replace(h, attrs=dict(h.attrs))


def remember_validated(key, header: Header) -> None:
    """Within :func:`reuse_validation`: the file of identity ``key`` (:func:`identity`, taken before its check)
    passed the check with ``header``; a later check of the unchanged file returns a copy of it."""
    if _VALIDATED is not None and key is not None:
        _VALIDATED[key] = dataclasses.replace(header, attrs=dict(header.attrs))
