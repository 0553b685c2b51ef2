"""Where fan-out work runs: a process pool on this machine (``local``) or Ray tasks (``ray``).

The offline tools hand a list of independent tasks to :func:`run_tasks`: shards of a dataset
(``simulate``), flights to replay and score (``evaluate-flights``), trainings (``train-fleet``,
``tune``). Each task's result depends only on its arguments (every task carries its seed), so
which engine, how many workers and in which order they finish change nothing but the time.

* ``local``: a :class:`concurrent.futures.ProcessPoolExecutor` (or this process for one
  worker). A worker that dies breaks the pool: the run stops with one line, and the tools'
  outputs are resumable (finished shards and models are kept), so the same command carries on.
* ``ray``: one Ray task per item on a cluster: ``address`` (or the ``RAY_ADDRESS`` environment
  variable) names one, else a local cluster of ``workers`` CPUs is started for the run and shut
  down after it. A task whose worker process dies is retried (``retries`` times) by Ray;
  exceptions raised by the task itself are not retried: a
  :class:`~landing_zone.errors.LandingZoneError` is raised here as it was, anything else
  with the worker's traceback. Ray ships
  functions and results between its processes with pickle, as a process pool does; no file the
  tools read is ever unpickled.

Ray is an optional dependency (``pip install 'landing_zone[ray]'``): without it the ``ray``
engine raises :class:`~landing_zone.errors.EngineError` saying how to get it.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from landing_zone.errors import EngineError, LandingZoneError

__all__ = ['ENGINES', 'INSTALL_HINT', 'check_engine', 'require_ray', 'run_tasks']

ENGINES = ('local', 'ray')
INSTALL_HINT = "--engine ray needs Ray: pip install 'landing_zone[ray]'"
# The object store of a local cluster: results here are small (figures, file names), and the
# default (30 % of memory) would reserve shared memory other processes on a 2-core
# development machine need.
_LOCAL_OBJECT_STORE = 256 * 1024 * 1024


def check_engine(engine: str, address: str | None = None) -> None:
    """Refuse an unknown engine, ``address`` without Ray, and Ray where it is not installed.

    Raises:
        EngineError: with one line saying what is wrong (and how to install Ray).
    """
    if engine not in ENGINES:
        raise EngineError(f'engine must be one of {", ".join(ENGINES)}, got {engine!r}')
    if address is not None and engine != 'ray':
        raise EngineError('--address names a Ray cluster: give it with --engine ray')
    if engine == 'ray':
        require_ray()


def require_ray() -> Any:
    """The ``ray`` module.

    Raises:
        EngineError: Ray is not installed (the message says how to install it).
    """
    try:
        import ray
    except ImportError:
        raise EngineError(INSTALL_HINT) from None
    return ray


def run_tasks(fn: Callable[[Any], Any], tasks: Sequence[Any], *, engine: str = 'local',
              workers: int | None = None, address: str | None = None, retries: int = 3,
              start_method: str | None = None, fresh: bool = False
              ) -> Iterator[tuple[int, Any]]:
    """Run ``fn(task)`` for every task; yield ``(index, result)`` as each one finishes.

    Args:
        fn: a module-level function (workers import it by name).
        tasks: its arguments, one per task (picklable).
        engine: ``local`` or ``ray``.
        workers: local: processes (None: one per usable core; 1: in this process); ray: the
            CPUs of the local cluster started when no cluster is named (ignored when one is).
        address: a Ray cluster's address (``ray://HOST:10001``, ``HOST:6379`` or ``auto``);
            None: ``RAY_ADDRESS`` if set, else a local cluster.
        retries: ray: times a task whose worker died is run again.
        start_method: local: the ``multiprocessing`` start method (None: the platform's).
        fresh: run every task in a process of its own (a worker ends after one task). For
            trainings: torch keeps process-wide state (its thread pool, oneDNN's primitive
            cache) that a worker's earlier tasks leave behind, and with it a training's last
            bits could depend on which tasks the worker ran before. Local fresh workers are
            spawned (``start_method`` is ignored).

    Raises:
        EngineError: bad arguments, Ray missing, or a worker that died (after the retries).
        LandingZoneError: as raised by a task (the first one to fail).
    """
    check_engine(engine, address)
    if workers is not None and (not isinstance(workers, int) or workers < 1):
        raise EngineError(f'workers must be a positive integer, got {workers!r}')
    if not isinstance(retries, int) or retries < 0:
        raise EngineError(f'retries must be a non-negative integer, got {retries!r}')
    if not tasks:
        return _in_process(fn, ())
    # The pool or the cluster starts here, before the caller's first next(): a caller that
    # forks (start_method='fork') must do so before it starts threads of its own.
    if engine == 'ray':
        return _run_ray(fn, tasks, workers, address, retries, fresh)
    return _run_local(fn, tasks, workers, 'spawn' if fresh else start_method, fresh)


def _usable_cores() -> int:
    if hasattr(os, 'sched_getaffinity'):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def _in_process(fn: Callable[[Any], Any], tasks: Sequence[Any]) -> Iterator[tuple[int, Any]]:
    for i, task in enumerate(tasks):
        yield i, fn(task)


def _run_local(fn: Callable[[Any], Any], tasks: Sequence[Any], workers: int | None,
               start_method: str | None, fresh: bool) -> Iterator[tuple[int, Any]]:
    n = min(workers or _usable_cores(), len(tasks))
    if n <= 1 and not fresh:
        return _in_process(fn, tasks)
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    pool = ProcessPoolExecutor(n, mp_context=multiprocessing.get_context(start_method),
                               max_tasks_per_child=1 if fresh else None)
    pending = {pool.submit(fn, task): i for i, task in enumerate(tasks)}
    return _drain_local(pool, pending, len(tasks))


def _drain_local(pool: Any, pending: dict[Any, int], total: int
                 ) -> Iterator[tuple[int, Any]]:
    from concurrent.futures import FIRST_COMPLETED, wait
    from concurrent.futures.process import BrokenProcessPool

    try:
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                i = pending.pop(fut)
                try:
                    result = fut.result()
                except BrokenProcessPool:
                    raise EngineError(
                        f'a worker process died running task {i} of {total} (killed, or '
                        'out of memory?); finished work is kept: rerun the same command to '
                        'carry on') from None
                yield i, result
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _run_ray(fn: Callable[[Any], Any], tasks: Sequence[Any], workers: int | None,
             address: str | None, retries: int, fresh: bool) -> Iterator[tuple[int, Any]]:
    ray = require_ray()
    import logging

    started = False
    if not ray.is_initialized():
        kwargs: dict[str, Any] = dict(include_dashboard=False, logging_level=logging.WARNING)
        if address is None and not os.environ.get('RAY_ADDRESS'):
            kwargs.update(num_cpus=workers or _usable_cores(),
                          object_store_memory=_LOCAL_OBJECT_STORE)
        try:
            ray.init(address=address, **kwargs)
        except (ConnectionError, RuntimeError, ValueError) as err:
            where = address or os.environ.get('RAY_ADDRESS') or 'a local cluster'
            raise EngineError(f'cannot start or reach Ray at {where}: '
                              f'{str(err).splitlines()[0] if str(err) else err}') from None
        started = True
    # num_cpus=1: one task per CPU of the cluster, as one process per core locally.
    options: dict[str, Any] = dict(num_cpus=1, max_retries=retries, retry_exceptions=False)
    if fresh:
        # max_calls=1 ends a worker after its task, but the task could still start on an idle
        # worker another function used before: Ray keeps one pool of workers per runtime
        # environment, so a runtime environment of their own gives fresh tasks new workers.
        options.update(max_calls=1, runtime_env={'env_vars': {'LANDING_ZONE_FRESH_WORKER': '1'}})
    remote = ray.remote(**options)(fn)
    try:
        pending = {remote.remote(task): i for i, task in enumerate(tasks)}
    except BaseException:
        if started:
            ray.shutdown()
        raise
    return _drain_ray(ray, pending, len(tasks), retries, started)


def _drain_ray(ray: Any, pending: dict[Any, int], total: int, retries: int, started: bool
               ) -> Iterator[tuple[int, Any]]:
    from ray import exceptions as rex

    try:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                i = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except rex.RayTaskError as err:
                    cause = err.cause if isinstance(err.cause, BaseException) else None
                    if isinstance(cause, LandingZoneError):  # bad input: one line
                        raise cause from None
                    raise  # a bug: with the worker's traceback
                except (rex.WorkerCrashedError, rex.NodeDiedError,
                        rex.ObjectLostError) as err:
                    raise EngineError(f'task {i} of {total}: its Ray worker died '
                                      f'{retries + 1} time(s) ({type(err).__name__}); finished '
                                      'work is kept: rerun the same command to carry on'
                                      ) from None
                except rex.RayError as err:  # out of memory, cancelled, unschedulable, ...
                    first = str(err).strip().splitlines()[0] if str(err).strip() else ''
                    raise EngineError(f'task {i} of {total} failed on Ray: '
                                      f'{type(err).__name__}: {first}') from None
                yield i, result
    finally:
        for ref in pending:
            try:
                ray.cancel(ref)
            except (rex.RayError, ValueError, TypeError):
                pass  # finished meanwhile: nothing to cancel
        if started:
            ray.shutdown()
