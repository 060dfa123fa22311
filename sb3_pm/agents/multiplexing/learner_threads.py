"""Running every learner's ``learn()`` at once, each in its own thread, in the baton's order."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from sb3_pm.agents.multiplexing.multiplexer import (
    POLL_INTERVAL,
    ParallelEnvMultiplexer,
    TeamAborted,
    TeamTimeout,
)


def learn_concurrently(
    models: Sequence[Any],
    hub: ParallelEnvMultiplexer,
    learn_kwargs: Sequence[dict[str, Any]],
    graceful_interrupt: bool = False,
    on_interrupt: Callable[[], None] | None = None,
) -> list[BaseException | None]:
    """Run ``model.learn(**kwargs)`` for every agent, each in its own thread, in baton order.

    Returns one entry per agent: ``None`` if it finished (or was stopped by the team), else the
    exception it raised. The first real error is re-raised by :func:`raise_first_error`.

    :param models: one SB3 algorithm per agent, in ``hub.agents`` order, each built on
        ``hub.vec_envs[i]``.
    :param learn_kwargs: keyword arguments of each ``learn()`` call.
    :param graceful_interrupt: on a first ``KeyboardInterrupt``, :meth:`~ParallelEnvMultiplexer.request_stop`
        and let the learners run to the next rollout barrier (where the ``on_sync`` hook stops them);
        a second one stops them at once. Either way the interrupt is re-raised once they stopped.
    :param on_interrupt: called on that first interrupt (to tell the user what happens next).
    """
    if len(models) != hub.n_agents or len(learn_kwargs) != hub.n_agents:
        raise ValueError(f"need one model and one set of learn() arguments per agent ({hub.n_agents})")
    hub.restart()
    errors: list[BaseException | None] = [None] * hub.n_agents

    def run(index: int) -> None:
        try:
            hub.acquire(index)
            models[index].learn(**learn_kwargs[index])
        except TeamAborted:
            pass  # another learner ended the run; its error (if any) is the one to report
        except BaseException as error:  # noqa: BLE001 - reported to the caller, never lost
            errors[index] = error
            hub.abort(f"{hub.agents[index]} raised {type(error).__name__}: {error}")
        finally:
            hub.finish(index)

    threads = [
        threading.Thread(target=run, args=(i,), name=f"sb3_pm-learner-{hub.agents[i]}", daemon=True)
        for i in range(hub.n_agents)
    ]
    hub.threads = threads
    for thread in threads:
        thread.start()
    interrupted = False
    while True:
        try:
            for thread in threads:
                while thread.is_alive():
                    if hub.timed_out is not None:
                        break  # a learner is stuck outside the env: the others have stopped; leave it
                    thread.join(POLL_INTERVAL)
            if hub.timed_out is not None:
                for thread in threads:  # the learners that were waiting unwind at once
                    thread.join(5 * POLL_INTERVAL)
                raise TeamTimeout(
                    f"team training stopped: {hub.timed_out}; a learner is stuck outside the environment "
                    "(a callback or train() that never returns?). If its work legitimately takes that "
                    "long, raise the team's wait_timeout"
                )
            break
        except KeyboardInterrupt:
            if graceful_interrupt and not interrupted:
                interrupted = True  # the learners go on to the next barrier, which stops them
                hub.request_stop()
                if on_interrupt is not None:
                    on_interrupt()
                continue
            _stop_now(hub, threads)
            raise
        except BaseException:
            _stop_now(hub, threads)
            raise
    if interrupted and hub.stopped is not None:
        raise KeyboardInterrupt  # the team stopped at a barrier; had it finished, that would be all
    return errors


def _stop_now(hub: ParallelEnvMultiplexer, threads: Sequence[threading.Thread]) -> None:
    """Abort the team (the caller was interrupted or timed out) and let the learners unwind."""
    hub.abort("interrupted")
    for thread in threads:
        thread.join(5 * POLL_INTERVAL)


def raise_first_error(errors: Iterable[BaseException | None]) -> None:
    """Re-raise the first exception in ``errors`` (the learner that failed first in agent order)."""
    for error in errors:
        if error is not None:
            raise error


__all__ = ["learn_concurrently", "raise_first_error"]
