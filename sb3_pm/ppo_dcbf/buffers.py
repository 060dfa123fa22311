"""A rollout buffer whose minibatch orders can be drawn before the update phase starts.

PPO's ``train()`` asks the buffer for one shuffled pass per epoch, and the buffer shuffles with
NumPy's global generator. Learners whose update phases run at the same time, each in its own thread
(:class:`~sb3_pm.agents.team.IndependentPPO` with ``concurrent_updates``), would then draw from that
one generator in an order the OS scheduler decides. :meth:`OrderedRolloutBuffer.draw_orders` draws
the epochs' orders in advance, while the learner still holds its turn and its own random stream is
loaded: the very permutations ``get()`` would have drawn one epoch at a time, so the update is the
same, bit for bit, whether it runs alone or next to others.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Generator
from typing import Any

import numpy as np
from sb3_contrib.common.maskable.buffers import MaskableDictRolloutBuffer, MaskableDictRolloutBufferSamples


class OrderedRolloutBuffer(MaskableDictRolloutBuffer):
    """sb3-contrib's ``MaskableDictRolloutBuffer`` that can take its minibatch orders in advance.

    Without drawn orders it is exactly the parent class. With them, each ``get()`` uses the next
    drawn order instead of the permutation the parent draws (which is then left unused).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        #: permutations of ``buffer_size * n_envs`` indices, one per coming ``get()``
        self.orders: deque[np.ndarray] = deque()
        self._order: np.ndarray | None = None
        self._cursor = 0

    def draw_orders(self, epochs: int) -> None:
        """Draw the next ``epochs`` minibatch orders now, from NumPy's global generator, in the
        sequence ``get()`` would draw them (one per epoch); replaces any left over."""
        size = self.buffer_size * self.n_envs
        self.orders.clear()
        self.orders.extend(np.random.permutation(size) for _ in range(epochs))  # noqa: NPY002 - as SB3

    def get(  # type: ignore[override]
        self, batch_size: int | None = None
    ) -> Generator[MaskableDictRolloutBufferSamples, None, None]:
        self._order = self.orders.popleft() if self.orders else None
        self._cursor = 0
        yield from super().get(batch_size)

    def _get_samples(  # type: ignore[override]
        self, batch_inds: np.ndarray, env: Any = None
    ) -> MaskableDictRolloutBufferSamples:
        if self._order is not None:  # the drawn order's next slice, of the size the parent asks for
            batch_inds = self._order[self._cursor : self._cursor + len(batch_inds)]
            self._cursor += len(batch_inds)
        return super()._get_samples(batch_inds, env)


__all__ = ["OrderedRolloutBuffer"]
