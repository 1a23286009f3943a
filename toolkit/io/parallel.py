"""Frames of one sequence in parallel: `--workers N` of every per-frame command.

`map_frames(fn, source, context, workers)` yields ``fn(frame, context)`` for every frame of
an ImageSource, **in order**, with the same results whatever `workers` is. With workers > 1
the frames go to worker processes started with *spawn* (OpenCV's and torch's thread pools
do not survive a fork reliably), each given `fn` and `context` once. Image files are
decoded in the workers (only paths travel), video frames are decoded here and sent as
arrays; at most ``2 * workers`` frames are in flight, so a long video is never held in
memory at once. Each worker runs OpenCV single-threaded: the workers are the parallelism.

Faults: a worker that dies (the kernel's OOM killer, a crash in C code) ends the run with
`WorkerDied`, a one-line InputError that says how it died, instead of waiting for its
frame for ever; an interrupt or an error stops every worker at once; a worker whose
command has gone (killed) ends by itself within a second. No more workers are started
than the CPUs this process may use and the memory available can hold (`worker_limit`),
nor more than there are frames.

`fn` must be a module-level function and `context` picklable (cameras, boards, pencils and
the like are).

Example
-------
>>> from pencilcal.toolkit.io.parallel import map_frames
>>> def size(frame, ctx):                                  # doctest: +SKIP
...     return frame.name, None if frame.image is None else frame.image.shape
>>> list(map_frames(size, open_images("frames/"), None, workers=2))  # doctest: +SKIP
"""
from __future__ import annotations

import multiprocessing
import os
import pickle
import queue
import signal
import threading
import warnings

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.images import read_frame

__all__ = ["map_frames", "Sized", "worker_limit", "WorkerDied", "WORKER_MEMORY_BYTES"]

#: Memory one worker is allowed for in `worker_limit` [bytes]: its interpreter with OpenCV
#: and numpy (about 100 MB), a 1080p frame and the detectors' working copies of it.
WORKER_MEMORY_BYTES = 512 * 1024 * 1024
# how often the parent looks whether its workers are alive while it waits [s]
_POLL_S = 0.2


class WorkerDied(InputError):
    """A worker process ended without finishing its frames (killed, or crashed)."""


def _available_memory():
    """Bytes of memory available to new processes (Linux's MemAvailable), or None."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def worker_limit():
    """(the most worker processes this machine can hold, why): the CPUs this process may
    use (its affinity), and no more than the available memory holds at
    `WORKER_MEMORY_BYTES` each; at least 1.

    >>> n, why = worker_limit()
    >>> n >= 1 and isinstance(why, str)
    True
    """
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = os.cpu_count() or 1
    limit, why = max(1, cpus), f"{cpus} CPU{'s' if cpus != 1 else ''} available to this process"
    mem = _available_memory()
    if mem is not None and mem // WORKER_MEMORY_BYTES < limit:
        limit = max(1, int(mem // WORKER_MEMORY_BYTES))
        why = f"{mem / 2**30:.1f} GiB of memory available, at {WORKER_MEMORY_BYTES // 2**20} MiB a worker"
    return limit, why


def _init_worker():
    import cv2

    # Ctrl-C goes to the whole process group: the parent alone handles it (and stops the
    # workers), so that no worker dies half-way through a frame with a traceback of its own
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # the parent's handlers are not theirs
    if hasattr(signal, "SIGHUP"):
        signal.signal(signal.SIGHUP, signal.SIG_DFL)
    cv2.setNumThreads(1)
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)


def _decode(decoding, frame):
    """The frame with its image (decoded here, in the worker, when only its path came);
    decoding: (gray, max_pixels, keep_colour) of the source (`images.read_frame`)."""
    if frame.image is not None or frame.error is not None or frame.path is None:
        return frame
    return read_frame(frame, *decoding)


def _packed(seq, ok, value, caught=()):
    """A result (and the warnings its frame raised) as bytes, pickled here: an exception
    that cannot be pickled travels as its message (the queue's own pickling, in a thread,
    would lose it and the parent wait)."""
    caught = [(str(w.message), w.category, w.filename, w.lineno) for w in caught]
    try:
        return pickle.dumps((seq, ok, value, caught), protocol=pickle.HIGHEST_PROTOCOL)
    except Exception as e:  # noqa: BLE001 - any pickling failure
        err = value if not ok else e
        caught = [(m, c if c.__module__ == "builtins" else RuntimeWarning, f, n) for m, c, f, n in caught]
        return pickle.dumps((seq, False, RuntimeError(f"{type(err).__name__}: {err}"), caught))


def _worker(fn, context, decoding, tasks, results, parent):
    """A worker's life: frames from `tasks` until None, their results to `results`; it ends
    by itself when its parent (the command) is gone."""
    _init_worker()
    while True:
        try:
            item = tasks.get(timeout=1.0)
        except queue.Empty:
            if os.getppid() != parent:
                return
            continue
        if item is None:
            return
        seq, frame = item
        # the frame's warnings go to the parent with its result and are raised there, where
        # the command decides how to show them (as with one process)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                out = (True, fn(_decode(decoding, frame), context))
            except Exception as e:  # noqa: BLE001 - raised again in the parent, in order
                out = (False, e)
        results.put(_packed(seq, *out, caught))


def _death(process):
    """How a worker process ended, in words."""
    code = process.exitcode
    if code is not None and code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        hint = " (the system ran out of memory: the kernel's OOM killer?)" if -code == signal.SIGKILL else ""
        return f"was killed by {name}{hint}"
    return f"exited with status {code}"


class _Workers:
    """`n` worker processes fed through two queues; `stop` ends them at once."""

    def __init__(self, n, fn, context, decoding):
        ctx = multiprocessing.get_context("spawn")
        self.tasks, self.results = ctx.Queue(), ctx.Queue()
        args = (fn, context, decoding, self.tasks, self.results, os.getpid())
        self.procs = [ctx.Process(target=_worker, args=args, daemon=True, name=f"pencilcal-worker-{i}")
                      for i in range(n)]
        # Workers start with SIGINT ignored (an ignored signal stays ignored across exec, and
        # Python then leaves it so): a Ctrl-C while they import must not kill them half-way,
        # with a traceback of their own; the parent alone handles it and stops them.
        main = threading.current_thread() is threading.main_thread()  # signals belong to it alone
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
        try:
            for p in self.procs:
                p.start()
        finally:
            if main:
                signal.signal(signal.SIGINT, previous)

    def result(self):
        """The next (seq, ok, value) from any worker, its frame's warnings raised here;
        WorkerDied when a worker has ended."""
        while True:
            try:
                seq, ok, value, caught = pickle.loads(self.results.get(timeout=_POLL_S))
                for message, category, filename, lineno in caught:
                    warnings.warn_explicit(message, category, filename, lineno)
                return seq, ok, value
            except queue.Empty:
                dead = [p for p in self.procs if p.exitcode is not None]
                if dead:
                    raise WorkerDied(f"worker process {dead[0].pid} {_death(dead[0])} before its frames were done "
                                     "(fewer --workers need less memory)") from None

    def finish(self):
        for _ in self.procs:
            self.tasks.put(None)
        for p in self.procs:
            p.join()

    def stop(self):
        """End every worker now (after finish: nothing left to end)."""
        for q in (self.tasks, self.results):
            q.cancel_join_thread()  # frames still queued must not hold this process at exit
        for p in self.procs:
            if p.exitcode is None:
                p.terminate()
        for p in self.procs:
            p.join(timeout=2.0)
            if p.exitcode is None:
                p.kill()
                p.join()
        for q in (self.tasks, self.results):
            q.close()


def map_frames(fn, source, context, workers=1):
    """Ordered ``fn(frame, context)`` over the frames of `source` (an ImageSource).

    workers: processes (at most `worker_limit`, and the number of frames when known; 1 or
    None: here, in this process). An exception in `fn` is raised here, in the order of the
    frames. An exception or an interrupt (Ctrl-C, SIGTERM raised as an exception in the
    main process) while results are awaited ends the workers at once: the caller's clean-up
    runs and the process exits within a moment, instead of waiting on frames in flight. A
    worker that dies raises `WorkerDied`.
    """
    n = min(int(workers or 1), worker_limit()[0])
    if getattr(source, "kind", None) == "images":
        n = min(n, max(1, len(source)))
    if n <= 1:
        for frame in source:
            yield fn(frame, context)
        return
    pool = _Workers(n, fn, context, (source.gray, source.max_pixels, getattr(source, "keep_colour", False)))
    try:
        window, sent, done, ready = 2 * n, 0, 0, {}
        refs = iter(source.refs())
        more = True
        while more or done < sent:
            while more and sent - done < window:
                ref = next(refs, None)
                if ref is None:
                    more = False
                    break
                pool.tasks.put((sent, ref))
                sent += 1
            while done not in ready and done < sent:
                seq, ok, value = pool.result()
                ready[seq] = (ok, value)
            if done < sent:
                ok, value = ready.pop(done)
                done += 1
                if not ok:
                    raise value
                yield value
        pool.finish()
    finally:
        pool.stop()


class Sized:
    """An iterable with a known length, for progress bars over `map_frames` results."""

    def __init__(self, it, n):
        self.it, self.n = it, n

    def __iter__(self):
        return iter(self.it)

    def __len__(self):
        return self.n
