"""The parts of a compiled kernel, run on a small pool of threads that an owner shuts down.

The density map is split into slabs ("parts", :data:`landing_zone.mapping.raytrace.PARTS`);
a kernel compiled with ``nogil=True`` is called once per part, and parts never write the same
memory, so threads need no atomics. Threads (the caller's included) take the next part from a
shared counter, so a thread the OS holds back on a busy machine delays nothing: the others
take its share. Why not ``numba.prange``: see below.
"""
from __future__ import annotations

import itertools
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numba as nb

__all__ = ['PartRunner', 'run_parts']


# Parts run on Python threads that pull them from a shared counter while the kernel releases
# the GIL. The alternative, numba.prange over the parts (OpenMP here), was measured on this
# shared 2-core machine with the integrate scene: 0.57M against 0.76M returns/s with another
# process busy on one core (its static split waits for the descheduled thread, and one call
# with 10k trivial rays took 16 ms against 0.7 ms), and never faster, so it went.


class _Batch:
    """Parts of one job handed out to whichever thread asks first."""

    def __init__(self, kernel: Callable[..., None], nparts: int, args: tuple[Any, ...]) -> None:
        self.kernel = kernel
        self.args = args
        self.nparts = nparts
        self.next = itertools.count()  # next() on a count is atomic under the GIL
        self.lock = threading.Lock()
        self.finished = 0
        self.all_done = threading.Event()
        self.error: BaseException | None = None

    def work(self) -> None:
        while True:
            part = next(self.next)
            if part >= self.nparts:
                return
            try:
                self.kernel(part, *self.args)
            except BaseException as err:  # surfaced in the caller's thread
                self.error = err
            with self.lock:
                self.finished += 1
                if self.finished == self.nparts:
                    self.all_done.set()


class PartRunner:
    """The helper threads that run the parts of a kernel beside the caller's thread.

    It owns its pool (started on first use, numba's thread count less the caller) and ends it
    in :meth:`close`; each :class:`~landing_zone.mapping.density_map.DensityMap` that runs in
    parallel has one. Threads (the caller's included) take the next part from a shared counter,
    so a thread the OS holds back does not hold up the others: a helper that starts late finds
    nothing left.
    """

    def __init__(self) -> None:
        self._pool: ThreadPoolExecutor | None = None
        self._lock = threading.Lock()

    def run(self, kernel: Callable[..., None], nparts: int, args: tuple[Any, ...]) -> None:
        """Call ``kernel(part, *args)`` for every part, on up to numba's number of threads.

        The kernel must be compiled with ``nogil=True`` and parts must not write the same
        memory.
        """
        threads = min(nb.get_num_threads(), nparts)
        if threads <= 1:
            for part in range(nparts):
                kernel(part, *args)
            return
        batch = _Batch(kernel, nparts, args)
        pool = self._executor()
        for _ in range(threads - 1):
            pool.submit(batch.work)
        batch.work()
        batch.all_done.wait()
        if batch.error is not None:
            raise batch.error

    def _executor(self) -> ThreadPoolExecutor:
        with self._lock:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(
                    # numba's config module sets its names at run time (no stubs)
                    max_workers=max(nb.config.NUMBA_NUM_THREADS - 1,  # type: ignore[attr-defined]
                                    1),
                    thread_name_prefix='raytrace')
            return self._pool

    def close(self) -> None:
        """End the helper threads (a later :meth:`run` starts new ones)."""
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True)


def run_parts(kernel: Callable[..., None], nparts: int, args: tuple[Any, ...],
              runner: PartRunner | None = None) -> None:
    """Call ``kernel(part, *args)`` for every part: on ``runner``'s threads, or in turn."""
    if runner is None:
        for part in range(nparts):
            kernel(part, *args)
        return
    runner.run(kernel, nparts, args)
