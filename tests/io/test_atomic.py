"""calib.io.atomic.output_set: the products written in the block appear together at its end, or none of them does;
the previous products stay untouched on any error or interruption; nothing hidden is left behind."""
from __future__ import annotations

import os
import signal
import threading

import pytest

from calib.io import atomic


def _files(folder):
    return {p.name: p.read_text() for p in sorted(folder.iterdir())}


def test_the_products_of_a_set_appear_only_at_its_end_all_together(tmp_path):
    (tmp_path / "a.txt").write_text("earlier a")
    with atomic.output_set():
        atomic.write_text(tmp_path / "a.txt", "new a")
        atomic.write_json({"x": 1}, tmp_path / "b.json")
        with atomic.output_set():   # a set inside a set joins it
            atomic.write_text(tmp_path / "c.md", "c")
        # nothing under a final name yet: the earlier product as it was, the new ones absent
        assert {n: t for n, t in _files(tmp_path).items() if not n.startswith(".")} == {"a.txt": "earlier a"}
        assert len([n for n in os.listdir(tmp_path) if n.startswith(".")]) == 3   # complete, under temporary names
    assert _files(tmp_path) == {"a.txt": "new a", "b.json": '{\n  "x": 1\n}\n', "c.md": "c"}


def test_a_product_written_twice_in_one_set_is_its_later_content(tmp_path):
    with atomic.output_set():
        atomic.write_text(tmp_path / "r.md", "first")
        atomic.write_text(tmp_path / "r.md", "second")
    assert _files(tmp_path) == {"r.md": "second"}


@pytest.mark.parametrize("exc", [KeyboardInterrupt, ValueError])
def test_an_error_or_interrupt_in_the_set_leaves_the_previous_products_and_nothing_else(tmp_path, exc):
    (tmp_path / "a.txt").write_text("earlier a")
    with pytest.raises(exc):
        with atomic.output_set():
            atomic.write_text(tmp_path / "a.txt", "new a")
            atomic.write_text(tmp_path / "b.txt", "new b")
            raise exc()
    assert _files(tmp_path) == {"a.txt": "earlier a"}


def test_a_signal_during_the_renames_is_raised_after_every_product_is_in_place(tmp_path, monkeypatch):
    """A Ctrl-C that comes between two renames must not leave half a set: it is held back and raised after."""
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("Python runs signal handlers in the main thread only")
    real = os.replace
    renamed = []

    def replace(src, dst):
        real(src, dst)
        renamed.append(os.path.basename(dst))
        if len(renamed) == 1:
            signal.raise_signal(signal.SIGINT)   # the handler runs now: with the set's hold, it only records it

    monkeypatch.setattr(os, "replace", replace)
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            with atomic.output_set():
                for n in ("a", "b", "c"):
                    atomic.write_text(tmp_path / n, n)
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler   # the handler is back
    finally:
        signal.signal(signal.SIGINT, old)
    assert renamed == ["a", "b", "c"]
    assert _files(tmp_path) == {"a": "a", "b": "b", "c": "c"}


def test_a_failed_rename_removes_the_products_not_yet_in_place(tmp_path):
    (tmp_path / "b").mkdir()   # a folder where a file should go: its rename fails
    with pytest.raises(OSError):
        with atomic.output_set():
            for n in ("a", "b", "c"):
                atomic.write_text(tmp_path / n, n)
    assert sorted(os.listdir(tmp_path)) == ["a", "b"] and (tmp_path / "b").is_dir()


def test_a_set_is_the_writing_thread_s_own(tmp_path):
    """Another thread's products are not held by this thread's set."""
    with atomic.output_set():
        t = threading.Thread(target=atomic.write_text, args=(tmp_path / "other", "o"))
        t.start()
        t.join()
        assert (tmp_path / "other").read_text() == "o"
        atomic.write_text(tmp_path / "mine", "m")
        assert not (tmp_path / "mine").exists()
    assert (tmp_path / "mine").read_text() == "m"


def test_an_interrupt_right_after_the_temporary_file_is_created_leaves_nothing(tmp_path, monkeypatch):
    real = atomic._create

    def create_then_interrupted(tmp):
        real(tmp)
        raise KeyboardInterrupt

    monkeypatch.setattr(atomic, "_create", create_then_interrupted)
    with pytest.raises(KeyboardInterrupt):
        atomic.write_text(tmp_path / "a.txt", "a")
    assert os.listdir(tmp_path) == []


def test_a_temporary_file_has_the_permissions_of_a_plain_open(tmp_path):
    old = os.umask(0o027)
    try:
        with atomic.atomic_path(tmp_path / "a.txt") as tmp:
            mode = os.stat(tmp).st_mode & 0o777
        with open(tmp_path / "plain", "w"):
            pass
        assert mode == os.stat(tmp_path / "plain").st_mode & 0o777 == 0o640
    finally:
        os.umask(old)


def test_a_write_into_another_writers_temporary_file_is_not_held_by_the_set(tmp_path):
    """calib.io.recording.write writes the netCDF atomically into its own temporary file, then validates that file:
    inside a set the inner write must land at once (else the file checked is empty), the product at the set's end."""
    with atomic.output_set():
        with atomic.atomic_path(tmp_path / "rec.nc") as outer:
            atomic.write_text(outer, "content")           # the inner writer: into the outer's temporary file
            assert outer.read_text() == "content"
        assert not (tmp_path / "rec.nc").exists()
    assert (tmp_path / "rec.nc").read_text() == "content"
    assert os.listdir(tmp_path) == ["rec.nc"]


def test_folders_made_for_a_set_that_failed_are_removed_again(tmp_path):
    (tmp_path / "kept").mkdir()
    with pytest.raises(KeyboardInterrupt):
        with atomic.output_set():
            atomic.write_text(tmp_path / "new" / "deep" / "a.txt", "a")
            atomic.write_text(tmp_path / "kept" / "sub" / "b.txt", "b")
            atomic.make_folder(tmp_path / "other")
            (tmp_path / "other" / "theirs.txt").write_text("not the set's")   # a folder no longer empty stays
            raise KeyboardInterrupt
    assert sorted(os.listdir(tmp_path)) == ["kept", "other"] and os.listdir(tmp_path / "kept") == []
    with atomic.output_set():   # a set that ends with its products keeps its folders
        atomic.write_text(tmp_path / "new" / "deep" / "a.txt", "a")
    assert (tmp_path / "new" / "deep" / "a.txt").read_text() == "a"
