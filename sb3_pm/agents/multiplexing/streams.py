"""One random stream per learner, carried through the process-wide generators.

SB3 learners draw from the process-wide generators: torch's default CPU generator (action sampling,
the estimator's minibatches), NumPy's legacy global ``RandomState`` (PPO's minibatch permutation)
and Python's ``random``. In a team, every learner runs in its own thread, so a shared stream would
make each learner's draws depend on what the others drew before it.

Instead, each learner owns a :class:`StreamState`. The multiplexer loads a learner's state into the
process-wide generators when that learner takes the baton and stores it back when it hands the
baton on. A learner's draws then depend only on its own seed and its own code path, never on the
interleaving of the team. That is what lets a checkpoint be taken at any rollout boundary, and a
resumed run continue bit for bit: the state of every stream is part of the checkpoint.

Only the learner holding the baton runs code that draws from the process-wide generators, so
swapping their state is safe. A learner updating side by side with others draws nothing from them:
its update's draws are made up front, or from a torch generator of its own
(:meth:`~sb3_pm.agents.multiplexing.multiplexer.ParallelEnvMultiplexer.enter_update`). Without the baton
(``strict_order=False``) streams are not used. Only the CPU generators are carried: on a GPU,
action sampling draws from the CUDA generator, which is shared.
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th


@dataclass
class StreamState:
    """The state of the three process-wide generators a learner draws from.

    :param python: ``random.getstate()``.
    :param numpy: ``np.random.get_state()`` (the legacy global ``RandomState``).
    :param torch: ``torch.get_rng_state()``, a ``(5056,)`` uint8 tensor (CPU generator).
    """

    python: tuple[Any, ...]
    numpy: Any
    torch: th.Tensor

    def state_dict(self) -> dict[str, Any]:
        """The three states as plain values (tuples of ints, a ``uint32`` and a ``uint8`` array),
        for a checkpoint (:mod:`sb3_pm.plain_state`)."""
        return {"python": self.python, "numpy": self.numpy, "torch": self.torch.clone()}

    @classmethod
    def from_state_dict(cls, state: dict[str, Any]) -> StreamState:
        """The stream a :meth:`state_dict` describes, checked by the generators themselves.

        :raises InputError: if one of the states is malformed.
        """
        from sb3_pm.errors import InputError

        try:
            python = tuple(state["python"])
            random.Random().setstate(python)
            numpy = tuple(state["numpy"])
            np.random.RandomState().set_state(numpy)
            torch = th.as_tensor(state["torch"], dtype=th.uint8)
            th.Generator().set_state(torch)
        except (KeyError, TypeError, ValueError, RuntimeError) as error:
            raise InputError(f"a malformed random stream state ({error})") from None
        return cls(python=python, numpy=numpy, torch=torch)


def seeded_stream(seed: int) -> StreamState:
    """The state the process-wide generators would have after ``set_random_seed(seed)`` (CPU)."""
    return StreamState(
        python=random.Random(seed).getstate(),
        numpy=np.random.RandomState(seed).get_state(),
        torch=th.Generator().manual_seed(seed).get_state(),
    )


def capture_stream(base: StreamState | None = None) -> StreamState:
    """The process-wide generators' current state; with ``base``, only torch's is read and the
    NumPy and Python states are ``base``'s (see :func:`load_stream`)."""
    if base is not None:
        return StreamState(python=base.python, numpy=base.numpy, torch=th.get_rng_state())
    numpy_state = np.random.get_state()  # noqa: NPY002 - the legacy global generator SB3 draws from
    return StreamState(python=random.getstate(), numpy=numpy_state, torch=th.get_rng_state())


def load_stream(state: StreamState, torch_only: bool = False) -> None:
    """Put ``state`` into the process-wide generators (only torch's with ``torch_only``).

    Torch's generator is swapped at every turn (it samples the actions); NumPy's and Python's only
    around a learner's update phase, where SB3 draws from them (PPO's minibatch permutation):
    swapping NumPy's state costs about 75 us, some 3% of an agent-step.
    """
    th.set_rng_state(state.torch)
    if not torch_only:
        random.setstate(state.python)
        np.random.set_state(state.numpy)  # noqa: NPY002 - SB3 draws from it


def learner_stream_seed(seed: int, num_timesteps: int, index: int) -> int:
    """The seed of learner ``index``'s stream for a ``learn()`` call that starts at ``num_timesteps``.

    A function of the team seed, the step count and the learner alone (NumPy ``SeedSequence``), so a
    continued ``learn()`` gets fresh streams that do not repeat the first call's draws.
    """
    entropy = [int(seed), int(num_timesteps), 1, int(index)]
    return int(np.random.SeedSequence(entropy).generate_state(1)[0])


def learner_streams(seed: int, num_timesteps: int, n_agents: int) -> list[StreamState]:
    """Fresh streams for a team's learners at a ``learn()`` call starting at ``num_timesteps``."""
    return [seeded_stream(learner_stream_seed(seed, num_timesteps, i)) for i in range(n_agents)]


__all__ = [
    "StreamState",
    "capture_stream",
    "learner_stream_seed",
    "learner_streams",
    "load_stream",
    "seeded_stream",
]
