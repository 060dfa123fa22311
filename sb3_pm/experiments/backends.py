"""Where the independent cells of a sweep run: a local process pool, or Ray.

Both backends take the same picklable job (a function and a list of argument dicts) and return
results in submission order, so the tables they produce are identical for the same seeds.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

from sb3_pm.errors import InputError
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
) -> list[Any]:
    """Run ``function(job)`` for every (picklable) job; results come back in the order of ``jobs``.

    :param backend: ``"local"`` (a process pool of ``n_jobs`` workers; ``n_jobs=1`` runs in this
        process, which keeps tracebacks simple) or ``"ray"`` (a local Ray instance, or the cluster
        at ``ray_address``).
    :param on_done: called as ``on_done(index, result)`` when a job finishes (progress reporting).
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
    pool = ProcessPoolExecutor(max_workers=min(n_jobs, len(jobs)), initializer=exit_with_parent)
    try:
        futures = {pool.submit(function, job): index for index, job in enumerate(jobs)}
        for future in as_completed(futures):
            index = futures[future]
            results[index] = future.result()
            if on_done:
                on_done(index, results[index])
    except BaseException:
        # Ctrl-C, a failed cell, SystemExit from a SIGTERM handler: the workers go too, now, instead
        # of the pool waiting for every running cell to finish.
        workers = list(getattr(pool, "_processes", {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for worker in workers:
            worker.terminate()
        raise
    pool.shutdown(wait=True)
    return results


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
