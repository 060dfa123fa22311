"""Where the independent cells of a sweep run: a local process pool, or Ray.

Both backends take the same picklable job (a function and a list of argument dicts) and return
results in submission order, so the tables they produce are identical for the same seeds.
"""

from __future__ import annotations

import os
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, as_completed, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

from sb3_pm.errors import InputError, Sb3PmError
from sb3_pm.machine import usable_cores

BACKENDS = ("local", "ray")


def default_jobs() -> int:
    """One job per core the process may use."""
    return usable_cores()


def run_jobs(
    function: Callable[[Any], Any],
    jobs: Sequence[Any],
    backend: str = "local",
    n_jobs: int | None = None,
    ray_address: str | None = None,
    on_done: Callable[[int, Any], None] | None = None,
    label: Callable[[Any], str] | None = None,
) -> list[Any]:
    """Run ``function(job)`` for every (picklable) job; results come back in the order of ``jobs``.

    :param backend: ``"local"`` (a process pool of ``n_jobs`` workers; ``n_jobs=1`` runs in this
        process, which keeps tracebacks simple) or ``"ray"`` (a local Ray instance, or the cluster
        at ``ray_address``).
    :param on_done: called as ``on_done(index, result)`` when a job finishes (progress reporting).
    :param label: names a job in messages (default ``job <index>``).
    :raises WorkerLost: on the local backend, once every other job has finished, for jobs whose
        worker process was killed twice (see :func:`_run_local`); Ray retries lost tasks itself.
    :raises ValueError: for an unknown backend.
    :raises ImportError: for ``"ray"`` when Ray is not installed (``pip install ray``, or
        ``pip install -e ".[ray]"`` in a checkout).
    """
    if backend not in BACKENDS:
        raise InputError(f"unknown backend {backend!r}; choose one of {BACKENDS}")
    if not jobs:
        return []
    if backend == "ray":
        return _run_ray(function, jobs, n_jobs, ray_address, on_done)
    n_jobs = n_jobs or default_jobs()
    results: list[Any] = [None] * len(jobs)
    if n_jobs == 1:
        for index, job in enumerate(jobs):
            results[index] = function(job)
            if on_done:
                on_done(index, results[index])
        return results
    return _run_local(function, jobs, n_jobs, on_done, label)


class WorkerLost(Sb3PmError):
    """Jobs whose worker process died twice (killed: the out-of-memory killer, ``kill -9``); the
    other jobs finished. ``lost`` holds their indices."""

    def __init__(self, message: str, lost: list[int]) -> None:
        super().__init__(message)
        self.lost = lost


def _marked(function: Callable[[Any], Any], job: Any, marker: str) -> Any:
    """``function(job)``, after creating ``marker``: a job whose marker exists when the pool breaks
    was running in it (the dead worker's, or a sibling's), one without had not started."""
    Path(marker).touch()
    return function(job)


def _end_pools(pools: Sequence[ProcessPoolExecutor]) -> None:
    """Ctrl-C, a failed job, SystemExit from a SIGTERM handler: the workers go too, now, instead of
    each pool waiting for its running jobs to finish."""
    for pool in pools:
        workers = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for worker in workers:
            worker.terminate()


def _run_local(
    function: Callable[[Any], Any],
    jobs: Sequence[Any],
    n_jobs: int,
    on_done: Callable[[int, Any], None] | None,
    label: Callable[[Any], str] | None,
) -> list[Any]:
    """The process pool, surviving lost workers.

    A worker killed from outside (the out-of-memory killer) breaks the whole pool: every job in it
    fails with ``BrokenProcessPool``. The jobs that had not started go on in a new pool; those that
    were running (the lost one and its siblings: the pool does not say which worker held which) are
    retried once, each in a process of its own, so a second loss is its own job's. A job lost there
    too is reported in one :class:`WorkerLost` once every other job has finished. A retried job
    starts again from what its first attempt left: a sweep's cells resume from their folders.
    """
    results: list[Any] = [None] * len(jobs)

    def names(indices: list[int]) -> str:
        return ", ".join(label(jobs[index]) if label else f"job {index}" for index in indices)

    def finish(index: int, result: Any) -> None:
        results[index] = result
        if on_done:
            on_done(index, result)

    with tempfile.TemporaryDirectory(prefix="sb3_pm-jobs-") as marks:
        pending, suspects, round_ = list(range(len(jobs))), [], 0
        while pending:
            round_ += 1
            pending, lost = _pool_round(function, jobs, pending, n_jobs, finish, f"{marks}/{round_}-")
            if lost:
                print(
                    f"warning: a worker process died (killed; out of memory?) while running {names(lost)}; "
                    "retrying each once in a process of its own",
                    file=sys.stderr,
                )
            suspects += lost
    failed = _retry_alone(function, jobs, suspects, n_jobs, finish)
    if failed:
        raise WorkerLost(
            f"the worker process running {names(failed)} died twice (killed; out of memory?); "
            f"the other {len(jobs) - len(failed)} job(s) finished",
            failed,
        )
    return results


def _pool_round(
    function: Callable[[Any], Any],
    jobs: Sequence[Any],
    indices: list[int],
    n_jobs: int,
    finish: Callable[[int, Any], None],
    marker: str,
) -> tuple[list[int], list[int]]:
    """Run ``indices`` in one pool until they finish or it breaks.

    :returns: ``(not started, lost)``: the jobs to run in a new pool, and those running when it broke.
    """
    pool = ProcessPoolExecutor(max_workers=min(n_jobs, len(indices)), initializer=exit_with_parent)
    futures = {pool.submit(_marked, function, jobs[index], f"{marker}{index}"): index for index in indices}
    finished: set[int] = set()
    try:
        for future in as_completed(futures):
            if isinstance(future.exception(), BrokenProcessPool):
                break
            finish(futures[future], future.result())  # a job's own exception ends the sweep
            finished.add(futures[future])
        else:
            pool.shutdown(wait=True)
            return [], []
        # Broken: keep what finished before the break; the rest by whether it had started.
        pool.shutdown(wait=True)
        unstarted, lost = [], []
        for future, index in futures.items():
            if index in finished:
                continue
            error = future.exception()
            if error is None:
                finish(index, future.result())
            elif not isinstance(error, BrokenProcessPool):
                raise error
            else:
                (lost if Path(f"{marker}{index}").exists() else unstarted).append(index)
        return unstarted, lost
    except BaseException:
        _end_pools([pool])
        raise


def _retry_alone(
    function: Callable[[Any], Any],
    jobs: Sequence[Any],
    indices: list[int],
    n_jobs: int,
    finish: Callable[[int, Any], None],
) -> list[int]:
    """Run each of ``indices`` in a one-worker pool of its own, ``n_jobs`` at a time.

    :returns: the jobs whose worker died again.
    """
    queue, failed = list(indices), []
    running: dict[Future[Any], tuple[int, ProcessPoolExecutor]] = {}
    try:
        while queue or running:
            while queue and len(running) < n_jobs:
                index = queue.pop(0)
                pool = ProcessPoolExecutor(max_workers=1, initializer=exit_with_parent)
                running[pool.submit(function, jobs[index])] = (index, pool)
            done, _ = wait(list(running), return_when=FIRST_COMPLETED)
            for future in done:
                index, pool = running.pop(future)
                pool.shutdown(wait=True)
                if isinstance(future.exception(), BrokenProcessPool):
                    failed.append(index)
                else:
                    finish(index, future.result())
    except BaseException:
        _end_pools([pool for _, pool in running.values()])
        raise
    return sorted(failed)


#: Seconds between a worker's checks that its parent is still alive.
PARENT_CHECK_SECONDS = 1.0


def exit_with_parent() -> None:
    """Make this worker process end when its parent ends (a pool initializer).

    A SIGKILLed parent runs no cleanup, so its workers would be adopted by init and go on training
    and writing into the sweep's folder. A daemon thread notices the new parent id within
    :data:`PARENT_CHECK_SECONDS` and ends the worker; the unfinished cell has no ``DONE`` file, so a
    resumed sweep trains it again. The parent is read here, in the worker: under the ``forkserver``
    start method it is the fork server, which ends with the sweep too.
    """
    parent_pid = os.getppid()

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_CHECK_SECONDS)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def _run_ray(
    function: Callable[[Any], Any],
    jobs: Sequence[Any],
    n_jobs: int | None,
    ray_address: str | None,
    on_done: Callable[[int, Any], None] | None,
) -> list[Any]:
    try:
        import ray
    except ImportError as error:
        raise ImportError(
            "the ray backend needs Ray: pip install ray (in a checkout of sb3_pm: pip install -e '.[ray]')"
        ) from error
    started_here = not ray.is_initialized()
    if started_here:
        if ray_address:
            ray.init(address=ray_address, log_to_driver=False)
        else:
            ray.init(num_cpus=n_jobs or default_jobs(), include_dashboard=False, log_to_driver=False)
    try:
        remote = ray.remote(num_cpus=1)(function)
        refs = [remote.remote(job) for job in jobs]
        index_of = {ref: i for i, ref in enumerate(refs)}
        results: list[Any] = [None] * len(jobs)
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            index = index_of[done[0]]
            results[index] = ray.get(done[0])
            if on_done:
                on_done(index, results[index])
        return results
    finally:
        if started_here:
            ray.shutdown()
