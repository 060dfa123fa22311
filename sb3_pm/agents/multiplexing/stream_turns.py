"""The multiplexer's handling of the learners' random streams, turn by turn.

:class:`LearnerStreams` is a part of
:class:`~sb3_pm.agents.multiplexing.multiplexer.ParallelEnvMultiplexer`: it loads a learner's stream
(:mod:`sb3_pm.agents.multiplexing.streams`) into the process-wide generators when the
learner takes the baton, stores it back when the learner hands the baton on, and opens the
learner's update phase, side by side with the others where every draw of it can be made up front.
It relies on the multiplexer's ``_cond``, ``n_agents``, ``strict_order`` and ``_pass_baton``.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import replace

import torch as th

from sb3_pm.agents.multiplexing.streams import StreamState, capture_stream, load_stream


class LearnerStreams:
    """Per-learner random streams for a multiplexer (a mixin; see the module docstring)."""

    _cond: threading.Condition
    n_agents: int
    strict_order: bool

    def _pass_baton(self, index: int) -> None:  # provided by the multiplexer
        raise NotImplementedError

    def _init_streams(self) -> None:
        #: one random stream per agent (see :mod:`sb3_pm.agents.multiplexing.streams`); None: the shared one
        self.streams: list[StreamState] | None = None
        #: per agent: its stream is loaded in the process-wide generators (all of it: "full")
        self._holds_stream = [False] * self.n_agents
        self._holds_full_stream = [False] * self.n_agents
        #: let learners run their update phases side by side (see :meth:`enter_update`)
        self.concurrent_updates = False
        #: per agent in a side-by-side update phase: the torch generator holding its stream
        self._update_generators: list[th.Generator | None] = [None] * self.n_agents

    def set_streams(self, streams: Sequence[StreamState] | None) -> None:
        """Give each agent its own random stream (one per agent, in agent order), or ``None``.

        :raises ValueError: if there is not one stream per agent, or the baton is off.
        """
        if streams is not None:
            if len(streams) != self.n_agents:
                raise ValueError(f"need one random stream per agent ({self.n_agents}), got {len(streams)}")
            if not self.strict_order:
                raise ValueError("per-agent random streams need strict_order=True (the baton)")
        self.streams = None if streams is None else list(streams)
        self._holds_stream = [False] * self.n_agents
        self._holds_full_stream = [False] * self.n_agents

    def _load_stream(self, index: int, full: bool = False) -> None:
        """Agent ``index`` took the baton: its random stream becomes the process-wide one (torch's
        generator only, unless ``full``: see :meth:`enter_update`)."""
        if self.streams is not None:
            load_stream(self.streams[index], torch_only=not full)
            self._holds_stream[index] = True
            self._holds_full_stream[index] = self._holds_full_stream[index] or full

    def _store_stream(self, index: int) -> None:
        """Agent ``index`` hands the baton on: keep where its random stream stands (all of it if
        its full stream was loaded since it took the baton, else torch's generator only)."""
        if self.streams is not None and self._holds_stream[index]:  # never another agent's state
            full = self._holds_full_stream[index]
            self.streams[index] = capture_stream(None if full else self.streams[index])
            self._holds_stream[index] = self._holds_full_stream[index] = False

    def enter_update(self, index: int, draw: Callable[[], None] | None = None) -> th.Generator | None:
        """Agent ``index`` (holding the baton) starts its update phase (rollout end to barrier).

        During a rollout only torch's generator is swapped per turn; SB3's learners draw from
        NumPy's and Python's generators only in the update phase (PPO's minibatch permutation), so
        all of the agent's stream is loaded here, and stored at the barrier.

        With :attr:`concurrent_updates` and a ``draw`` that makes, now, every NumPy draw of the
        update phase (:meth:`~sb3_pm.ppo_dcbf.buffers.OrderedRolloutBuffer.draw_orders`), the agent
        hands the baton on at once and updates side by side with the others. Its remaining draws
        come from the returned torch generator, which holds its stream (the estimator's minibatch
        orders); the policy has no dropout, so nothing else in an update draws. The arithmetic is
        the same either way, so the parameters are too, bit for bit.

        :returns: the agent's own torch generator for a side-by-side update, else ``None``.
        """
        with self._cond:
            self._load_stream(index, full=True)
            if draw is None or not self.concurrent_updates or self.streams is None:
                return None
            draw()
            self._store_stream(index)
            generator = th.Generator()
            generator.set_state(self.streams[index].torch)
            self._update_generators[index] = generator
            self._pass_baton(index)
            self._cond.notify_all()
            return generator

    def _end_update(self, index: int) -> bool:
        """If agent ``index`` updates side by side, keep its generator's state as its stream's."""
        generator = self._update_generators[index]
        if generator is None:
            return False
        assert self.streams is not None
        self.streams[index] = replace(self.streams[index], torch=generator.get_state())
        self._update_generators[index] = None
        return True


__all__ = ["LearnerStreams"]
