"""The one atomic writer under whole-system faults: a full disk, a read-only or vanished
folder, two writers, a signal during the commit. Outputs appear whole or not at all, the
earlier output is kept byte for byte, no temporary file is left, and the message names the
output."""
from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import (atomic_folder, atomic_path, atomic_paths, atomic_write, check_writable,
                                        signals_deferred, staging_folder)
from tests.faults import files_in, fill, remount, tmpfs


def test_full_disk_keeps_the_earlier_output_and_leaves_no_temporary_file(tmp_path):
    with tmpfs(tmp_path / "small", "64k") as d:
        out = d / "out.json"
        out.write_bytes(b"keep me\n")
        with pytest.raises(InputError) as e:
            atomic_write(out, b"x" * 200_000, force=True)
        assert str(e.value) == f"{out}: cannot write: no space left on device (the disk is full); the earlier " \
                               f"{out} is kept"
        assert files_in(d) == {"out.json": b"keep me\n"}


def test_full_disk_without_an_earlier_output_leaves_nothing(tmp_path):
    with tmpfs(tmp_path / "small", "64k") as d:
        fill(d)
        with pytest.raises(InputError) as e:
            atomic_write(d / "out.json", "{}\n")
        assert str(e.value).endswith("cannot write: no space left on device (the disk is full); nothing was written")
        assert sorted(files_in(d)) == ["filler"]


def test_read_only_folder_is_refused_before_any_work(tmp_path):
    with tmpfs(tmp_path / "ro", readonly=True) as d:
        with pytest.raises(InputError) as e:
            check_writable(d / "out.json")
        assert str(e.value) == f"{d / 'out.json'}: cannot write in folder {d} (read-only file system)"
        with pytest.raises(InputError) as e:
            staging_folder(d / "sim")
        assert str(e.value) == f"{d / 'sim'}: cannot write in folder {d} (read-only file system)"


def test_folder_made_read_only_during_the_run(tmp_path):
    with tmpfs(tmp_path / "fs", "1m") as d:
        out = d / "out.json"
        out.write_bytes(b"keep me\n")
        with pytest.raises(InputError) as e:
            with atomic_path(out, force=True) as tmp:
                tmp.write_text("new\n")
                remount(d, readonly=True)
        assert str(e.value) == f"{out}: cannot write: read-only file system; the earlier {out} is kept"
        # the temporary file cannot be removed from a read-only file system: it is all that is left
        assert files_in(d)["out.json"] == b"keep me\n" and len(files_in(d)) == 2


def test_folder_removed_during_the_run(tmp_path):
    folder = tmp_path / "gone"
    folder.mkdir()
    with pytest.raises(InputError) as e:
        with atomic_path(folder / "out.json") as tmp:
            tmp.write_text("{}")
            tmp.unlink()
            folder.rmdir()
    assert str(e.value) == f"{folder / 'out.json'}: cannot write: folder {folder} no longer exists (removed during " \
                           "the run?); nothing was written"


def test_an_output_written_meanwhile_by_another_run_is_kept_without_force(tmp_path):
    out = tmp_path / "out.json"
    with pytest.raises(InputError) as e:
        with atomic_path(out) as tmp:
            tmp.write_text("mine\n")
            out.write_text("theirs\n")  # the other run put its whole output there first
    assert "written meanwhile" in str(e.value) and "--force" in str(e.value)
    assert files_in(tmp_path) == {"out.json": b"theirs\n"}


def test_several_outputs_stand_or_fall_together(tmp_path, monkeypatch):
    """The second rename fails: the first output is put back as it was."""
    a, b = tmp_path / "a.yaml", tmp_path / "b.json"
    a.write_text("old a\n")
    b.write_text("old b\n")
    real = os.replace
    calls = []

    def flaky(src, dst):
        calls.append(dst)
        if Path(dst) == b:
            raise OSError(5, "Input/output error", str(dst))
        return real(src, dst)

    monkeypatch.setattr(os, "replace", flaky)
    with pytest.raises(InputError) as e:
        with atomic_paths([a, b], force=True) as (ta, tb):
            ta.write_text("new a\n")
            tb.write_text("new b\n")
    monkeypatch.setattr(os, "replace", real)
    assert "input/output error" in str(e.value)
    assert files_in(tmp_path) == {"a.yaml": b"old a\n", "b.json": b"old b\n"}


def test_a_signal_during_the_commit_waits_until_every_output_is_in_place(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    with pytest.raises(KeyboardInterrupt):
        with atomic_paths([a, b]) as (ta, tb):
            ta.write_text("1")
            tb.write_text("2")
            # the commit starts right after this block: Ctrl-C arrives in the middle of it
            real = os.link

            def link_then_interrupt(src, dst):
                real(src, dst)
                os.kill(os.getpid(), signal.SIGINT)

            os.link = link_then_interrupt
    os.link = real
    assert files_in(tmp_path) == {"a.txt": b"1", "b.txt": b"2"}


def test_signals_deferred_delivers_after_the_block():
    seen = []
    with pytest.raises(KeyboardInterrupt):
        with signals_deferred():
            os.kill(os.getpid(), signal.SIGINT)
            seen.append("after the signal")
    assert seen == ["after the signal"]


def test_atomic_folder_names_the_output_not_its_staging_folder(tmp_path):
    with tmpfs(tmp_path / "small", "64k") as d:
        with pytest.raises(InputError) as e:
            with atomic_folder(d / "sim") as tmp:
                (tmp / "images").mkdir()
                (tmp / "images" / "000.png").write_bytes(b"x" * 200_000)
        assert str(e.value) == f"{d / 'sim'}: cannot write: no space left on device (the disk is full); nothing was " \
                               "written"
        assert files_in(d) == {} and os.listdir(d) == []
