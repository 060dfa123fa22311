"""How many learners of a team run their update phase at the same time.

With side-by-side updates
(:attr:`~sb3_pm.agents.multiplexing.multiplexer.ParallelEnvMultiplexer.concurrent_updates`) every learner
starts its ``train()`` and estimator fit at its rollout's end, each in its own thread.
With many learners on few cores (16 learners on 2 cores for the 16-agent regime on ``paper-200``)
the threads then take turns on the cores and on the GIL, and each one's working set is pushed out
of the caches by the others, so a 16-learner team trains faster with two updates at a time than
with all sixteen (research/LOG.md §3i, "Update slots"). :class:`UpdateSlots` lets at most
``count`` learners be in their update phase at once; the others wait for a slot at their
rollout's end. A learner that cannot update side by side (``target_kl`` set) updates holding the
baton, one at a time, and takes no slot: in a team that mixes both kinds, up to ``count + 1``
updates may run at once.

Which learner updates when does not change what it computes: each update draws only from its own
generator and runs the same arithmetic, so the parameters are the same bit for bit whatever the
count (``tests/test_update_slots.py``).
"""

from __future__ import annotations

import threading

import torch as th

from sb3_pm.errors import InputError
from sb3_pm.machine import usable_cores


def default_update_slots() -> int:
    """One slot per core this process may use, divided by torch's threads per update."""
    return max(1, usable_cores() // max(1, th.get_num_threads()))


class UpdateSlots:
    """At most :attr:`count` holders at once, each named by its learner's index.

    A counting semaphore that knows who holds a slot, so that a learner that stops (an error, the
    end of training) gives back only a slot it holds, and only once.
    """

    def __init__(self, count: int) -> None:
        if isinstance(count, bool) or not isinstance(count, int) or count < 1:
            raise InputError(f"update slots must be a positive integer, got {count!r}")
        self.count = count
        self._holders: set[int] = set()
        self._cond = threading.Condition()

    def take(self, index: int, timeout: float) -> bool:
        """Take a slot for learner ``index``, waiting up to ``timeout`` seconds; ``False`` if none
        became free (the caller checks whether the team was aborted, then waits again)."""
        with self._cond:
            if index in self._holders:
                return True
            if not self._cond.wait_for(lambda: len(self._holders) < self.count, timeout):
                return False
            self._holders.add(index)
            return True

    def give_back(self, index: int) -> None:
        """Learner ``index`` leaves its update phase (a no-op if it holds no slot)."""
        with self._cond:
            if index in self._holders:
                self._holders.remove(index)
                self._cond.notify()

    @property
    def holders(self) -> frozenset[int]:
        """The learners in their update phase now."""
        with self._cond:
            return frozenset(self._holders)


__all__ = ["UpdateSlots", "default_update_slots"]
