"""A rollout buffer whose minibatch orders can be drawn before the update phase starts.

PPO's ``train()`` asks the buffer for one shuffled pass per epoch, and the buffer shuffles with
NumPy's global generator. Learners whose update phases run at the same time, each in its own thread
(:class:`~sb3_pm.agents.training.team.IndependentPPO` with ``concurrent_updates``), would then draw from that
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
    drawn order and draws nothing.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        #: permutations of ``buffer_size * n_envs`` indices, one per coming ``get()`` (set first:
        #: the parent's constructor calls :meth:`reset`)
        self.orders: deque[np.ndarray] = deque()
        super().__init__(*args, **kwargs)

    def draw_orders(self, epochs: int) -> None:
        """Draw the next ``epochs`` minibatch orders now, from NumPy's global generator, in the
        sequence ``get()`` would draw them (one per epoch); replaces any left over."""
        size = self.buffer_size * self.n_envs
        self.orders.clear()
        self.orders.extend(np.random.permutation(size) for _ in range(epochs))  # noqa: NPY002 - as SB3

    def get(  # type: ignore[override]
        self, batch_size: int | None = None
    ) -> Generator[MaskableDictRolloutBufferSamples, None, None]:
        """Minibatches in the next drawn order; without one, exactly the parent's ``get()``.

        With a drawn order nothing is drawn here, so updates running side by side never touch
        NumPy's global generator.
        """
        if not self.orders:
            yield from super().get(batch_size)
            return
        order = self.orders.popleft()
        self._flatten_once()
        total = self.buffer_size * self.n_envs
        step = total if batch_size is None else batch_size
        for start in range(0, total, step):
            yield self._get_samples(order[start : start + step])

    def reset(self) -> None:
        super().reset()
        self.orders.clear()

    def _flatten_once(self) -> None:
        """Turn the ``(n_steps, n_envs, ...)`` storage into ``(n_steps * n_envs, ...)`` once per
        rollout, as the parent's ``get()`` does before its first minibatch."""
        if self.generator_ready:
            return
        for key, observations in self.observations.items():
            self.observations[key] = self.swap_and_flatten(observations)
        for name in ("actions", "values", "log_probs", "advantages", "returns", "action_masks"):
            setattr(self, name, self.swap_and_flatten(getattr(self, name)))
        self.generator_ready = True


__all__ = ["OrderedRolloutBuffer"]
