"""The multiplexer's running state as plain values, for checkpoints.

:class:`HubState` gives :class:`~sb3_pm.agents.multiplexing.multiplexer.ParallelEnvMultiplexer` a
``state_dict()`` / ``load_state_dict()`` pair: every env copy's state
(:class:`~sb3_pm.envs.env_state.EnvState`), the running episode returns and lengths, the last
observation of every agent in every copy, and the learners' random streams
(:mod:`sb3_pm.agents.multiplexing.streams`). Arrays, numbers and generator states only: a
checkpoint stores them with :mod:`sb3_pm.plain_state`, which runs nothing when read.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from sb3_pm.agents.multiplexing.streams import StreamState
from sb3_pm.errors import InputError

if TYPE_CHECKING:
    from sb3_pm.agents.multiplexing.multiplexer import ParallelEnvMultiplexer


class HubState:
    """The ``state_dict()`` / ``load_state_dict()`` pair of the multiplexer."""

    def state_dict(self: ParallelEnvMultiplexer) -> dict[str, Any]:  # type: ignore[misc]
        """What the team's next steps depend on in the multiplexer, taken at a rollout barrier."""
        return {
            "envs": [env.state_dict() for env in self.envs],
            "ep_returns": self._ep_returns.copy(),
            "ep_lengths": self._ep_lengths.copy(),
            "last_obs": [[dict(obs) for obs in per_env] for per_env in self._last_obs],
            "streams": None if self.streams is None else [stream.state_dict() for stream in self.streams],
        }

    def load_state_dict(self: ParallelEnvMultiplexer, state: dict[str, Any]) -> list[StreamState] | None:  # type: ignore[misc]
        """Put back a :meth:`state_dict` of a multiplexer built with the same settings; returns the
        saved random streams (a team hands them to its next ``learn()``).

        The env copies carry on from where they were: no seeded reset is pending.

        :raises InputError: if the state does not fit (another number of copies or agents).
        """
        try:
            if not isinstance(state, dict):
                raise InputError("the saved multiplexer state is not a mapping")
            envs, last_obs = state["envs"], state["last_obs"]
            if len(envs) != self.n_envs or len(last_obs) != self.n_agents:
                raise InputError("the saved multiplexer state does not match the team (copies or agents)")
            ep_returns = np.asarray(state["ep_returns"], dtype=np.float64)
            ep_lengths = np.asarray(state["ep_lengths"], dtype=np.int64)
            if ep_returns.shape != self._ep_returns.shape or ep_lengths.shape != self._ep_lengths.shape:
                raise InputError("the saved episode counters do not match the team")
            for env, env_state in zip(self.envs, envs):
                env.load_state_dict(env_state)
            self._ep_returns[:] = ep_returns
            self._ep_lengths[:] = ep_lengths
            self._last_obs = [[dict(obs) for obs in per_env] for per_env in last_obs]
            streams = state["streams"]
            restored = None if streams is None else [StreamState.from_state_dict(s) for s in streams]
        except (KeyError, TypeError, AttributeError) as error:
            raise InputError(f"the saved multiplexer state is incomplete or malformed ({error!r})") from None
        self._explicit_seed = None
        self._agent_seeds = [None] * self.n_agents
        return restored


__all__ = ["HubState"]
