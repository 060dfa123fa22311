"""One PettingZoo ``ParallelEnv`` (``n_envs`` copies of it) seen as one SB3 ``VecEnv`` per agent.

Each agent of a decentralized team is its own, unmodified SB3 learner. A learner only knows how to
drive a single-agent ``VecEnv``, while the environment needs every agent's action before it can
step. :class:`ParallelEnvMultiplexer` bridges the two:

* it owns ``n_envs`` copies of the parallel env and hands out one
  :class:`~sb3_pm.agents.multiplexing.agent_vec_env.AgentVecEnv` per agent;
* each learner runs its own ``learn()`` in its own thread
  (:func:`~sb3_pm.agents.multiplexing.learner_threads.learn_concurrently`);
* an agent's ``step_wait`` (and ``reset``) submits its action and blocks until every agent has
  submitted; the last one steps all copies at once and publishes every agent's slice.

**Turn order (the baton).** Threads share torch's and NumPy's global random generators, so two
learners running at the same time would draw from them in an order decided by the OS scheduler,
and no two runs would be alike. A baton, passed ``agent_0 -> agent_1 -> ... -> agent_{n-1} ->
agent_0``, makes every stretch of learner code between two env interactions (policy forward,
callbacks, and ``train()`` unless updates run side by side) run alone, in a fixed order, so a run
is bit-for-bit reproducible from its seed. ``strict_order=False`` drops the baton (agents submit in
any order), for experiments only.

**Side-by-side updates.** With :attr:`ParallelEnvMultiplexer.concurrent_updates`, a learner that
can make every random draw of its update phase up front (:meth:`~ParallelEnvMultiplexer.enter_update`)
hands the baton on at its rollout's end and runs ``train()``, its estimator fit and its callbacks'
``on_rollout_start`` next to the others, without the baton, until the rollout barrier.

Each learner also draws from its own random stream, swapped into the process-wide generators at
its turns (:mod:`sb3_pm.agents.multiplexing.stream_turns`), so its draws do not depend on the others'.

**Rollout barrier.** :class:`~sb3_pm.agents.multiplexing.agent_vec_env.RolloutBarrier`, a callback every team
learner carries last, makes all learners meet at the start of each rollout (after every
``train()`` and estimator fit). There the team's :attr:`ParallelEnvMultiplexer.on_sync` hook runs
alone, with every learner at the same point: that is where checkpoints are taken, and where a stop
requested by Ctrl-C takes effect.

**Episode ends.** The env ends every episode by truncation at ``max_cycles``. As in SB3's
``DummyVecEnv`` with a ``TimeLimit``, a finished copy is reset at once; the step reports
``done=True``, ``info["terminal_observation"]`` (the last real observation, so PPO bootstraps from
it) and ``info["TimeLimit.truncated"]``. Like SB3's ``Monitor``, ``info["episode"]`` holds the
agent's return ``r``, length ``l`` and wall time ``t``, so ``rollout/ep_rew_mean`` is logged; the
env's own ``info["metrics"]`` is passed through.

**Failure.** If a learner raises, or stops early (a callback returned ``False``), the multiplexer
is aborted: every agent blocked in ``step_wait`` raises :class:`TeamAborted`, which
:func:`~sb3_pm.agents.multiplexing.learner_threads.learn_concurrently` swallows, and the original error is
re-raised to the caller. Blocked agents wake every :data:`POLL_INTERVAL` to check for an abort; a
``timeout`` bounds how long an agent waits for the others, counting only the time the process ran
(:class:`~sb3_pm.agents.multiplexing.awake_deadline.AwakeDeadline`: a sweep suspended for an hour resumes).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs

from sb3_pm.agents.multiplexing.agent_vec_env import AgentVecEnv
from sb3_pm.agents.multiplexing.awake_deadline import AwakeDeadline
from sb3_pm.agents.multiplexing.hub_state import HubState
from sb3_pm.agents.multiplexing.stream_turns import LearnerStreams
from sb3_pm.agents.multiplexing.update_slots import UpdateSlots

#: How often (seconds) a blocked agent re-checks the abort flag even without a notification.
POLL_INTERVAL = 0.5


class TeamAborted(RuntimeError):
    """Raised inside a learner blocked on the multiplexer when the team is being shut down."""


class TeamTimeout(RuntimeError):
    """An agent waited longer than the multiplexer's ``timeout`` for the others: one is stuck."""


class MultiplexerError(RuntimeError):
    """The agents disagreed about what to do next (e.g. some reset while others stepped)."""


class ParallelEnvMultiplexer(HubState, LearnerStreams):
    """Steps ``n_envs`` copies of a PettingZoo ``ParallelEnv`` for agents that act in separate threads.

    :param env_fns: one factory per env copy, each returning a fresh ``ParallelEnv`` whose
        ``possible_agents`` act every step and whose episodes end for all agents at once.
    :param strict_order: pass a baton so learner code runs in a fixed agent order (reproducible).
    :param timeout: seconds an agent may wait for the others before the team is aborted
        (``None``: wait forever, still waking every :data:`POLL_INTERVAL` to check for aborts).
    """

    def __init__(
        self,
        env_fns: Sequence[Callable[[], Any]],
        strict_order: bool = True,
        timeout: float | None = None,
    ) -> None:
        if not env_fns:
            raise ValueError("the multiplexer needs at least one env copy")
        self.envs = [fn() for fn in env_fns]
        self.n_envs = len(self.envs)
        first = self.envs[0]
        self.agents: list[str] = list(first.possible_agents)
        self.n_agents = len(self.agents)
        for env in self.envs[1:]:
            if list(env.possible_agents) != self.agents:
                raise ValueError("every env copy must have the same possible_agents")
        self.strict_order = strict_order
        self.timeout = timeout
        #: why the team was aborted on a timeout (``None``: no timeout happened)
        self.timed_out: str | None = None
        self.observation_spaces = {agent: first.observation_space(agent) for agent in self.agents}
        self.action_spaces = {agent: first.action_space(agent) for agent in self.agents}

        self._cond = threading.Condition()
        self._round = 0  # index of the joint step being gathered
        self._kinds: list[str | None] = [None] * self.n_agents  # "reset" / "step" submitted this round
        self._actions = np.zeros((self.n_agents, self.n_envs), dtype=np.int64)
        self._results: list[tuple[Any, ...] | None] = [None] * self.n_agents
        self._result_round = -1  # last round whose results are published
        self._baton = 0
        self._finished = [False] * self.n_agents
        self._aborted: str | None = None
        self._explicit_seed: int | None = None
        self._agent_seeds: list[int | None] = [None] * self.n_agents
        #: called after every joint step with the number of agent-steps taken (progress bars)
        self.on_round: Callable[[int], None] | None = None
        #: called at every rollout barrier, every learner waiting; a returned string stops the team
        #: with that reason (see :class:`RolloutBarrier`)
        self.on_sync: Callable[[], str | None] | None = None
        self._init_streams()
        #: the learner threads of the last ``learn()`` (a new one waits for none of them)
        self.threads: list[threading.Thread] = []
        #: set by :meth:`request_stop`: the ``on_sync`` hook should stop the team at the next barrier
        self.stop_requested = False
        #: the reason the last ``on_sync`` stopped the team, if it did
        self.stopped: str | None = None
        #: with side-by-side updates, how many learners may be in their update phase at once
        #: (``None``: all of them); see :mod:`sb3_pm.agents.multiplexing.update_slots`
        self.update_slots: UpdateSlots | None = None

        # Per agent and copy: running return; per copy: running length (Monitor-style stats).
        self._ep_returns = np.zeros((self.n_agents, self.n_envs), dtype=np.float64)
        self._ep_lengths = np.zeros(self.n_envs, dtype=np.int64)
        self._t_start = time.time()
        self._last_obs: list[list[dict[str, Any]]] = [[{} for _ in range(self.n_envs)] for _ in self.agents]
        #: per agent, the batched observation object its ``VecEnv`` returned last (what its learner
        #: keeps as ``_last_obs`` and acts on next), ``None`` before the first reset
        self.published: list[VecEnvObs | None] = [None] * self.n_agents
        self.vec_envs = [AgentVecEnv(self, i) for i in range(self.n_agents)]

    # ------------------------------------------------------------------ public
    def agent_env(self, agent: str | int) -> AgentVecEnv:
        """The ``VecEnv`` of one agent, by name or index."""
        return self.vec_envs[agent if isinstance(agent, int) else self.agents.index(agent)]

    def seed(self, seed: int | None) -> None:
        """Seed the next joint reset: copy ``k`` is reset with ``seed + k``."""
        with self._cond:
            self._explicit_seed = seed

    def abort(self, reason: str) -> None:
        """Wake every blocked agent with :class:`TeamAborted`; the first reason is kept."""
        with self._cond:
            if self._aborted is None:
                self._aborted = reason
            self._cond.notify_all()

    @property
    def aborted(self) -> str | None:
        """The reason the team was aborted, or ``None``."""
        return self._aborted

    def request_stop(self) -> None:
        """Ask the ``on_sync`` hook to stop the team at the next rollout barrier (Ctrl-C)."""
        with self._cond:
            self.stop_requested = True
            self._cond.notify_all()

    def sync(self, index: int) -> None:
        """Agent ``index`` waits at the rollout barrier until every agent reaches it."""
        self._submit(index, "sync", None)

    def restart(self) -> None:
        """Make the multiplexer usable for another ``learn()`` after all agents finished or aborted.

        The env copies keep their state, so a continued run picks up mid-episode.
        """
        alive = [thread.name for thread in self.threads if thread.is_alive()]
        if alive:
            raise MultiplexerError(
                f"learner threads of the previous learn() are still running ({', '.join(alive)}); "
                "it was stopped at once and they have not unwound yet"
            )
        with self._cond:
            self.stop_requested = False
            self.stopped = None
            self.timed_out = None
            self._update_generators = [None] * self.n_agents
            self._kinds = [None] * self.n_agents
            self._results = [None] * self.n_agents
            self._round = 0
            self._result_round = -1
            self._baton = 0
            self._finished = [False] * self.n_agents
            self._aborted = None

    def take_update_slot(self, index: int) -> None:
        """Agent ``index``, updating side by side, waits for one of the :attr:`update_slots`.

        The wait counts against :attr:`timeout` like any other: a learner stuck in its update
        holds its slot, and the ones waiting for it time the team out.

        :raises TeamAborted: if the team is aborted, or times out, before it gets a slot (a learner
            that sees the abort once it has a slot gives the slot back instead of updating).
        """
        slots = self.update_slots
        if slots is None:
            return
        deadline = AwakeDeadline(self.timeout, POLL_INTERVAL)
        wait = POLL_INTERVAL if self.timeout is None else min(POLL_INTERVAL, self.timeout)
        while not slots.take(index, wait):
            remaining = deadline.remaining()
            if remaining is not None:  # wake at the deadline, not up to a poll interval after it
                wait = max(0.0, min(POLL_INTERVAL, remaining))
                if self._aborted is None and remaining <= 0:
                    with self._cond:
                        self._time_out(self._waited_too_long(index, "an update slot"))
            if self._aborted is not None:
                raise TeamAborted(self._aborted)
        if self._aborted is not None:
            slots.give_back(index)
            raise TeamAborted(self._aborted)

    def give_back_update_slot(self, index: int) -> None:
        """Agent ``index`` leaves its update phase (a no-op if it holds no slot)."""
        if self.update_slots is not None:
            self.update_slots.give_back(index)

    def finish(self, index: int) -> None:
        """Agent ``index``'s learner is done: hand the baton on and never wait for it again."""
        self.give_back_update_slot(index)  # a learner that stops inside its update phase
        with self._cond:
            self._finished[index] = True
            self._kinds[index] = None
            if not self._end_update(index) and self._baton == index:
                self._store_stream(index)
                self._pass_baton(index)
            self._maybe_complete()
            self._cond.notify_all()

    def acquire(self, index: int) -> None:
        """Block until agent ``index`` holds the baton (a learner thread calls this first)."""
        with self._cond:
            self._wait(index, lambda: not self.strict_order or self._baton == index)
            self._load_stream(index, full=True)

    def close(self) -> None:
        for env in self.envs:
            env.close()

    # ---------------------------------------------------------------- internal
    def _wait(self, index: int, ready: Callable[[], bool]) -> None:
        """Wait (holding ``_cond``) until ``ready()``; raise :class:`TeamAborted` on abort or timeout."""
        deadline: AwakeDeadline | None = None  # set at the first slice: most calls find ready() at once
        while True:
            if self._aborted is not None:
                raise TeamAborted(self._aborted)
            if ready():
                return
            wait = POLL_INTERVAL
            if deadline is None:
                deadline = AwakeDeadline(self.timeout, POLL_INTERVAL)
            remaining = deadline.remaining()
            if remaining is not None:
                if remaining <= 0:
                    self._time_out(self._waited_too_long(index, "the other agents"))
                    raise TeamAborted(self._aborted)
                wait = min(wait, remaining)
            self._cond.wait(wait)

    def _waited_too_long(self, index: int, what: str) -> str:
        return f"{self.agents[index]} waited more than {self.timeout} s for {what}"

    def _time_out(self, reason: str) -> None:
        """Abort the team for a timeout (holding ``_cond``); the first reason is kept."""
        if self._aborted is None:
            self._aborted = reason
            self.timed_out = reason
        self._cond.notify_all()

    def _pass_baton(self, index: int) -> None:
        """Give the baton to the next unfinished agent after ``index`` (in ring order)."""
        for offset in range(1, self.n_agents + 1):
            candidate = (index + offset) % self.n_agents
            if not self._finished[candidate]:
                self._baton = candidate
                return
        self._baton = -1

    def _submit(self, index: int, kind: str, actions: np.ndarray | None) -> tuple[Any, ...]:
        """Record agent ``index``'s request for the current round, wait for the round, return its slice."""
        with self._cond:
            if self._aborted is not None:
                raise TeamAborted(self._aborted)
            if self._kinds[index] is not None:
                raise MultiplexerError(f"{self.agents[index]} submitted twice in one round")
            my_round = self._round
            self._kinds[index] = kind
            if actions is not None:
                self._actions[index] = actions
            if self._end_update(index):
                if kind != "sync":
                    raise MultiplexerError(f"{self.agents[index]} stepped during its update phase")
            elif self.strict_order:
                self._store_stream(index)
                self._pass_baton(index)
            try:
                self._maybe_complete()
            except Exception as error:  # an env or hook error ends the whole team, reported by this agent
                source = "the rollout barrier" if kind == "sync" else "the environment"
                self._aborted = f"{source} raised {type(error).__name__}: {error}"
                self._cond.notify_all()
                raise
            self._cond.notify_all()
            self._wait(
                index,
                lambda: self._result_round >= my_round and (not self.strict_order or self._baton == index),
            )
            self._load_stream(index)
            result = self._results[index]
            self._results[index] = None
            assert result is not None
            return result

    def _maybe_complete(self) -> None:
        """Run the joint reset/step once every unfinished agent has submitted (holding ``_cond``)."""
        pending = [i for i in range(self.n_agents) if not self._finished[i]]
        if not pending or any(self._kinds[i] is None for i in pending):
            return
        if any(self._finished):
            # A learner stopped while others still want to act: no joint step can happen again.
            stopped = [self.agents[i] for i in range(self.n_agents) if self._finished[i]]
            self._aborted = f"{', '.join(stopped)} stopped training before the rest of the team"
            return
        kinds = set(self._kinds)
        if len(kinds) != 1:
            asked = ", ".join(f"{self.agents[i]}: {self._kinds[i]}" for i in range(self.n_agents))
            raise MultiplexerError(
                f"agents disagree about the next joint call ({asked}); every learner of a team must "
                "step, reset and start rollouts together (same n_steps, n_envs and total timesteps)"
            )
        if kinds == {"reset"}:
            self._joint_reset()
        elif kinds == {"sync"}:
            self._joint_sync()
        else:
            self._joint_step()
        self._kinds = [None] * self.n_agents
        self._result_round = self._round
        self._round += 1

    def _joint_sync(self) -> None:
        """Every agent is at the rollout barrier: run the ``on_sync`` hook, alone."""
        self._results = [() for _ in range(self.n_agents)]
        if self.strict_order:  # the next rollout starts with the first agent, as after any round
            self._pass_baton(self.n_agents - 1)
        reason = None if self.on_sync is None else self.on_sync()
        if reason is not None:
            self.stopped = reason
            self._aborted = reason

    def _joint_reset(self) -> None:
        seed = self._explicit_seed
        if seed is None:
            seed = next((s for s in self._agent_seeds if s is not None), None)
        self._explicit_seed = None
        self._agent_seeds = [None] * self.n_agents
        per_env = []
        for k, env in enumerate(self.envs):
            observations, infos = env.reset(seed=None if seed is None else seed + k)
            per_env.append((observations, infos))
        self._ep_returns[:] = 0.0
        self._ep_lengths[:] = 0
        for i, agent in enumerate(self.agents):
            self._last_obs[i] = [obs[agent] for obs, _ in per_env]
            self.published[i] = self._stack(agent, self._last_obs[i])
            self._results[i] = (self.published[i], [dict(infos.get(agent, {})) for _, infos in per_env])

    def _joint_step(self) -> None:
        n, e = self.n_agents, self.n_envs
        rewards = np.zeros((n, e), dtype=np.float32)
        dones = np.zeros(e, dtype=bool)
        new_obs: list[list[dict[str, Any]]] = [[{}] * e for _ in range(n)]
        infos_out: list[list[dict[str, Any]]] = [[{}] * e for _ in range(n)]
        for k, env in enumerate(self.envs):
            joint = {agent: int(self._actions[i, k]) for i, agent in enumerate(self.agents)}
            observations, step_rewards, terminations, truncations, infos = env.step(joint)
            self._ep_lengths[k] += 1
            ended = [bool(terminations[a] or truncations[a]) for a in self.agents]
            if any(ended) and not all(ended):
                raise MultiplexerError(
                    "an episode ended for some agents but not others; "
                    "the multiplexer needs all agents to end together"
                )
            for i, agent in enumerate(self.agents):
                rewards[i, k] = step_rewards[agent]
                self._ep_returns[i, k] += step_rewards[agent]
                infos_out[i][k] = dict(infos.get(agent, {}))
                new_obs[i][k] = observations[agent]
            if ended[0]:
                dones[k] = True
                elapsed = round(time.time() - self._t_start, 6)
                for i, agent in enumerate(self.agents):
                    info = infos_out[i][k]
                    info["terminal_observation"] = observations[agent]
                    # SB3 bootstraps from the terminal observation only for time-limit ends.
                    info["TimeLimit.truncated"] = bool(truncations[agent] and not terminations[agent])
                    info["episode"] = {
                        "r": round(float(self._ep_returns[i, k]), 6),
                        "l": int(self._ep_lengths[k]),
                        "t": elapsed,
                    }
                    self._ep_returns[i, k] = 0.0
                self._ep_lengths[k] = 0
                reset_obs, _ = env.reset()
                for i, agent in enumerate(self.agents):
                    new_obs[i][k] = reset_obs[agent]
        for i, agent in enumerate(self.agents):
            self._last_obs[i] = new_obs[i]
            self.published[i] = self._stack(agent, new_obs[i])
            self._results[i] = (self.published[i], rewards[i].copy(), dones.copy(), infos_out[i])
        if self.on_round is not None:
            self.on_round(n * e)

    def _stack(self, agent: str, observations: list[dict[str, Any]]) -> VecEnvObs:
        """Batch one agent's per-copy observations the way ``DummyVecEnv`` does (fresh arrays)."""
        space = self.observation_spaces[agent]
        if isinstance(space, spaces.Dict):
            return {
                key: np.stack([np.asarray(obs[key], dtype=sub.dtype) for obs in observations])
                for key, sub in space.spaces.items()
            }
        return np.stack([np.asarray(obs, dtype=space.dtype) for obs in observations])


__all__ = ["POLL_INTERVAL", "MultiplexerError", "ParallelEnvMultiplexer", "TeamAborted", "TeamTimeout"]
