"""Whole-system faults for tests: a small or read-only file system, another user, the
installed command. Each needs the machine to allow it (mounting takes root); where it does
not, the test is skipped with the reason."""
from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest


def _mount(args, where):
    r = subprocess.run(["mount", *args, str(where)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.strip() or 'mount failed'}): mounting needs root "
                    "(CAP_SYS_ADMIN)")


@contextlib.contextmanager
def tmpfs(where, size="64k", readonly=False):
    """A tmpfs of `size` mounted at the folder `where` (made if absent) for the block: a
    real file system that fills up (ENOSPC) or refuses every write (EROFS)."""
    if os.name != "posix" or shutil.which("mount") is None:
        pytest.skip("no mount(8) on this machine: a real full or read-only file system cannot be made")
    where = Path(where)
    where.mkdir(parents=True, exist_ok=True)
    _mount(["-t", "tmpfs", "-o", f"size={size}{',ro' if readonly else ''}", "tmpfs"], where)
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


def remount(where, readonly):
    """Make the tmpfs at `where` read-only (or writable again), its files kept."""
    r = subprocess.run(["mount", "-o", f"remount,{'ro' if readonly else 'rw'}", str(where)], capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stderr


def fill(where):
    """Fill the file system of `where` up to its last block (a file that stays)."""
    fd = os.open(Path(where) / "filler", os.O_WRONLY | os.O_CREAT, 0o644)
    try:
        with contextlib.suppress(OSError):
            while os.write(fd, b"\0" * 4096):
                pass
    finally:
        os.close(fd)


def pencilcal_command():
    """The installed `pencilcal` command, as a user runs it: the console script beside this
    interpreter (else `python -m pencilcal.cli.main`)."""
    script = Path(sys.executable).parent / "pencilcal"
    return [str(script)] if script.is_file() else [sys.executable, "-m", "pencilcal.cli.main"]


def wait_for(cond, timeout):
    """Whether `cond()` came true within `timeout` seconds (asked every 50 ms)."""
    import time

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.05)
    return False


def files_in(folder):
    """{relative path: bytes} of every file under `folder` (hidden ones too): what a run left
    behind, byte for byte."""
    folder = Path(folder)
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def without_privileges():
    """The prefix that runs a command without root's power to read and write whatever it
    likes (CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH), so that a file's permissions stop it as
    they stop a user: [] when this process is not root; skip when it cannot drop them."""
    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.skip("running as root and no setpriv(1) to drop root's file permissions: a mode 000 file is "
                    "readable to root")
    caps = "-dac_override,-dac_read_search"
    return [setpriv, f"--bounding-set={caps}", f"--inh-caps={caps}"]


@contextlib.contextmanager
def stalled_mjpeg_server(jpegs):
    """An HTTP MJPEG source (multipart/x-mixed-replace, as IP cameras serve it) that sends
    the frames `jpegs` (bytes) and then holds every connection open without a byte more: a
    live source that stopped sending. Yields its URL."""
    import socket
    import threading
    import time

    srv = socket.socket()
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)
    stop = threading.Event()

    def serve(conn):
        with contextlib.suppress(OSError), conn:
            conn.recv(65536)
            conn.sendall(b"HTTP/1.0 200 OK\r\nContent-Type: multipart/x-mixed-replace; boundary=frame\r\n\r\n")
            for f in jpegs:
                conn.sendall(b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: %d\r\n\r\n" % len(f) + f
                             + b"\r\n")
                time.sleep(0.05)
            stop.wait()

    def accept():
        with contextlib.suppress(OSError):
            while not stop.is_set():
                conn, _ = srv.accept()
                threading.Thread(target=serve, args=(conn,), daemon=True).start()

    threading.Thread(target=accept, daemon=True).start()
    try:
        yield f"http://127.0.0.1:{srv.getsockname()[1]}/stream.mjpg"
    finally:
        stop.set()
        srv.close()
