"""Worker processes under faults: results in order whatever the worker count, at most
2 x workers frames held at once, a worker killed by the OOM killer said at once (not waited
for), warnings and unpicklable exceptions carried back to the parent."""
from __future__ import annotations

import os
import pickle
import signal
import time
import warnings

import numpy as np
import pytest

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.images import Frame
from pencilcal.toolkit.io.parallel import WorkerDied, map_frames, worker_limit

needs_two = pytest.mark.skipif(worker_limit()[0] < 2, reason="this machine holds one worker process: nothing to "
                                                              "run in parallel")


class Frames:
    """A video-like source of `n` decoded frames that counts how many it has handed out."""

    kind, gray, max_pixels = "video", False, 10**8

    def __init__(self, n):
        self.n, self.taken = n, 0

    def __len__(self):
        return self.n

    def refs(self):
        for i in range(self.n):
            self.taken += 1
            yield Frame(f"frame_{i:06d}", i, np.full((16, 16), i, np.uint8))

    __iter__ = refs


def mean_of(frame, ctx):
    return frame.index, float(frame.image.mean()) * ctx


def fail_on_three(frame, ctx):
    if frame.index == 3:
        raise InputError(f"{frame.name}: refused")
    return frame.index


def die_on_two(frame, ctx):
    if frame.index == 2:
        os.kill(os.getpid(), signal.SIGKILL)  # what the OOM killer does
    time.sleep(0.05)
    return frame.index


def warn_on_one(frame, ctx):
    if frame.index == 1:
        np.log(np.zeros(1))  # divide by zero: a RuntimeWarning in the worker
    return frame.index


class Unpicklable(Exception):
    def __init__(self, a, b):
        super().__init__(f"{a} {b}")

    def __reduce__(self):
        raise pickle.PicklingError("not this one")


def raise_unpicklable(frame, ctx):
    raise Unpicklable(frame.name, "odd")


@pytest.mark.slow
@needs_two
def test_results_in_order_and_the_first_error_in_order():
    assert list(map_frames(mean_of, Frames(12), 2.0, workers=2)) == list(map_frames(mean_of, Frames(12), 2.0))
    got = []
    with pytest.raises(InputError, match="frame_000003: refused"):
        for x in map_frames(fail_on_three, Frames(12), None, workers=2):
            got.append(x)
    assert got == [0, 1, 2]


@pytest.mark.slow
@needs_two
def test_at_most_two_frames_per_worker_are_held():
    src = Frames(200)
    it = map_frames(mean_of, src, 1.0, workers=2)
    assert next(it) == (0, 0.0)
    assert src.taken <= 2 * 2 + 1  # the window, and the one that refilled it
    it.close()


@pytest.mark.slow
@needs_two
def test_a_killed_worker_is_said_at_once():
    t0 = time.monotonic()
    with pytest.raises(WorkerDied, match=r"worker process \d+ was killed by SIGKILL \(the system ran out of memory"):
        list(map_frames(die_on_two, Frames(20), None, workers=2))
    assert time.monotonic() - t0 < 60  # it used to wait for the lost frame for ever


@pytest.mark.slow
@needs_two
def test_worker_warnings_and_unpicklable_errors_reach_the_parent():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert list(map_frames(warn_on_one, Frames(4), None, workers=2)) == [0, 1, 2, 3]
    assert [str(w.message) for w in caught] == ["divide by zero encountered in log"]
    with pytest.raises(RuntimeError, match="Unpicklable: frame_000000 odd"):
        list(map_frames(raise_unpicklable, Frames(2), None, workers=2))


def test_worker_limit_is_what_the_machine_holds():
    n, why = worker_limit()
    assert 1 <= n <= (os.cpu_count() or 1) and why
