""":class:`IndependentPPO`: a team of independent SB3 learners, one per agent, sharing nothing.

Each agent is its own SB3 algorithm (``DCBFPPO`` by default, or sb3-contrib's ``MaskablePPO`` or
plain ``PPO``) with its own parameters, buffers and optimizer. They are stepped together through a
:class:`~sb3_pm.agents.multiplexing.multiplexer.ParallelEnvMultiplexer`, each learner in its own
thread, in a fixed turn order, each drawing from its own random stream, so a team run is
reproducible from its seed and can be checkpointed and resumed bit for bit on the CPU with one
torch thread (:mod:`sb3_pm.agents.training.checkpoints`). It acts as every trained team does
(:class:`~sb3_pm.agents.deployment.rule.DeploymentRule`), so evaluation drives it as a baseline.

A saved team is a folder of one SB3 zip per agent and a manifest
(:mod:`sb3_pm.agents.deployment.saved_teams`); loading it runs nothing stored in it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.utils import get_device

from sb3_pm.agents.deployment.saved_teams import MANIFEST
from sb3_pm.agents.deployment.transfer import on_graph, transfer_problem
from sb3_pm.agents.multiplexing.multiplexer import ParallelEnvMultiplexer
from sb3_pm.agents.multiplexing.streams import StreamState
from sb3_pm.agents.training.checkpoints import (
    CheckpointSchedule,
    TrainingInterrupted,
    find_checkpoint,
    restore_state,
)
from sb3_pm.agents.training.learned_team import LearnedTeam
from sb3_pm.agents.training.learner_callbacks import (
    CallbackArg,
    EpisodeMetricsCallback,
    close_loggers,
)
from sb3_pm.agents.training.learner_record import plain_hyperparams, saved_hyperparams
from sb3_pm.agents.training.learners import agent_seed, check_same, learner_kwargs
from sb3_pm.agents.training.rollout_batching import RolloutBatcher
from sb3_pm.agents.training.team_learning import run_team_learning
from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphFamily, GraphLike
from sb3_pm.policies.settings import check_advice_source
from sb3_pm.team_interface import Team

logger = logging.getLogger(__name__)

#: Default ``wait_timeout`` (seconds) of a team's learners.
DEFAULT_WAIT_TIMEOUT = 1800.0


class IndependentPPO(LearnedTeam):
    """A team of independent PPO-style learners on one persistent-monitoring graph.

    :param graph: a preset name, a ``.graphml`` path or a :class:`GraphSpec`; or a graph family
        (``"family:er"``, a :class:`~sb3_pm.graphs.GraphFamily`) to train on a new graph every
        episode, deployed afterwards on any graph with :meth:`on_graph`.
    :param n_agents: team size.
    :param env_kwargs: keyword arguments of :func:`sb3_pm.envs.persistent_monitoring_v0.parallel_env`
        (not ``graph``/``n_agents``). An algorithm without action masks (``ppo``) gets
        ``illegal_action="stay"`` unless set, since it can pick any node.
    :param algo: ``"dcbf_ppo"``, ``"maskable_ppo"``, ``"ppo"`` or an algorithm class; ``None``
        picks ``dcbf_ppo`` when it is importable, else ``maskable_ppo``.
    :param policy: the policy (alias or class); ``None`` uses the algorithm's default.
    :param n_envs: env copies each learner collects from (the same for every agent).
    :param seed: seeds the env copies and, through :func:`agent_seed`, each learner.
    :param hyperparams: keyword arguments of the algorithm shared by all agents (``n_steps``,
        ``learning_rate`` with ``lin_`` schedules, ``policy_kwargs`` with class names ...).
    :param per_agent: ``{agent_name: {key: value}}`` overrides on top of ``hyperparams``.
    :param tensorboard_log: folder for TensorBoard logs (one run per agent), or ``None``.
    :param verbose: SB3 verbosity of every learner.
    :param device: torch device of every learner.
    :param strict_order: run learners in a fixed turn order (bit-for-bit reproducible).
    :param concurrent_updates: let the learners' update phases (``train()``, the estimator fit and
        the callbacks' ``on_rollout_start``/``on_training_end``) run side by side, each in its own
        thread, where every random draw of an update can be made before it starts (DCBF-PPO learners
        on CPU without ``target_kl``). The parameters are the same, bit for bit, as with ``False``;
        Callbacks that share state between learners must then be thread-safe.
    :param deploy_temperature: how the trained team acts by default (:attr:`deploy_temperature`):
        ``None`` by the argmax, a positive number by sampling at that temperature. Saved with the
        team; training never reads it.
    :param deploy_filter: the DCBF rules the trained team acts under
        (:attr:`~sb3_pm.agents.training.learned_team.LearnedTeam.deploy_filter`), ``{"neglect_bound": B,
        "neglect_scope": S}`` with ``"leave_cleared": True`` for rule 9 and ``"pass_held": True``
        for rule 10 (with either the bound may be left out), or ``None``. Saved with the team;
        :meth:`learn` trains without it.
    :param wait_timeout: seconds a learner may wait for its teammates (their ``train()`` included)
        or for an update slot (:attr:`update_slots`), before training stops with
        :class:`~sb3_pm.agents.multiplexing.multiplexer.TeamTimeout`, naming it;
        ``None`` waits for ever (default: 30 minutes). Only the time the process runs counts: a
        sweep suspended (``SIGSTOP``) for longer goes on when it is resumed
        (:class:`~sb3_pm.agents.multiplexing.awake_deadline.AwakeDeadline`).
    """

    name = "ippo"
    MANIFEST_FORMAT = "sb3_pm.team/2"
    OLD_FORMATS = ("sb3_pm.team/1",)
    resizable = True
    #: while training, run the learners' rollout passes as one stacked pass per joint step where it
    #: applies (:mod:`sb3_pm.agents.training.rollout_batching`; the same parameters bit for bit)
    batched_rollouts: bool = True
    #: with side-by-side updates, how many learners may run their update phase at once: ``None``
    #: (one per usable core, over torch's threads) or a positive integer; the same parameters
    #: either way (:mod:`sb3_pm.agents.multiplexing.update_slots`)
    update_slots: int | None = None

    def __init__(
        self,
        graph: GraphLike | GraphFamily,
        n_agents: int = 4,
        env_kwargs: Mapping[str, Any] | None = None,
        algo: str | type | None = None,
        policy: str | type | None = None,
        n_envs: int = 1,
        seed: int = 0,
        hyperparams: Mapping[str, Any] | None = None,
        per_agent: Mapping[str, Mapping[str, Any]] | None = None,
        tensorboard_log: str | Path | None = None,
        verbose: int = 0,
        device: str = "cpu",
        strict_order: bool = True,
        wait_timeout: float | None = DEFAULT_WAIT_TIMEOUT,
        concurrent_updates: bool = True,
        deploy_temperature: float | None = None,
        deploy_filter: Mapping[str, Any] | None = None,
        _init_models: bool = True,
    ) -> None:
        self._set_problem(graph, n_agents, n_envs, seed, algo, policy, env_kwargs, deploy_temperature)
        self._deploy_filter = self._checked_deploy_filter(deploy_filter)
        self.verbose = verbose
        self.device = device
        self.tensorboard_log = None if tensorboard_log is None else str(tensorboard_log)
        self.hyperparams = dict(hyperparams or {})
        self.per_agent = {agent: dict(values) for agent, values in (per_agent or {}).items()}

        self.hub = ParallelEnvMultiplexer(
            [self._make_env] * self.n_envs, strict_order=strict_order, timeout=wait_timeout
        )
        # Per-learner streams swap the CPU generators only: side by side is for CPU learners.
        self.hub.concurrent_updates = bool(
            concurrent_updates and strict_order and get_device(device).type == "cpu"
        )
        self.agents: list[str] = list(self.hub.agents)
        unknown = sorted(set(self.per_agent) - set(self.agents))
        if unknown:
            raise InputError(f"per-agent overrides for unknown agents {unknown}; the team has {self.agents}")
        self.models: dict[str, Any] = {}
        #: random streams restored from a checkpoint, used by the next ``learn(reset_num_timesteps=False)``
        self._resume_streams: list[StreamState] | None = None
        #: the checkpoint this team was restored from, if any
        self.checkpoint: Path | None = None
        if _init_models:
            kwargs = {agent: self.agent_kwargs(agent) for agent in self.agents}
            check_same({agent: kw.get("n_steps", 2048) for agent, kw in kwargs.items()}, "n_steps")
            for i, agent in enumerate(self.agents):
                agent_kwargs = kwargs[agent]
                policy_i = agent_kwargs.pop("policy", self.policy)
                self.models[agent] = self.algo_class(
                    policy_i,
                    self.hub.vec_envs[i],
                    seed=agent_seed(self.seed, i),
                    tensorboard_log=self.tensorboard_log,
                    verbose=verbose,
                    device=device,
                    **agent_kwargs,
                )
            # Seed the env copies last: learner construction also asks for a seed (SB3 calls env.seed).
            self.hub.seed(self.seed)
            try:
                check_advice_source(self.models, self.env_kwargs)
                self._apply_deploy_temperature(self.deploy_temperature)
                if self._deploy_filter is not None:
                    self._check_training_bound()
                self._apply_deploy_filter()  # here too, so a filter it cannot take fails before training
            except InputError:  # a deployment rule for learners without the DCBF policy
                self.close()
                raise
            if isinstance(self.graph, GraphFamily):
                # A family team acts on a graph only through on_graph(): refuse what cannot.
                problem = transfer_problem(self)
                if problem is not None:
                    self.close()
                    raise InputError(
                        f"a team trained on the graph family {self.graph.name!r} must transfer: {problem}"
                    )

    # ------------------------------------------------------------ building
    def _make_env(self) -> Any:
        from sb3_pm.envs import persistent_monitoring_v0

        return persistent_monitoring_v0.parallel_env(
            graph=self.graph, n_agents=self.n_agents, **self.env_kwargs
        )

    def agent_kwargs(self, agent: str) -> dict[str, Any]:
        """The algorithm's keyword arguments for ``agent`` (see :func:`.learners.learner_kwargs`)."""
        return learner_kwargs(self.hyperparams, self.per_agent.get(agent, {}), agent, self.n_envs)

    # ------------------------------------------------------------- training
    @property
    def num_timesteps(self) -> int:
        """Timesteps taken by each learner (they are equal: the learners step together)."""
        return int(self.models[self.agents[0]].num_timesteps)

    @property
    def rollout_size(self) -> int:
        """Steps each learner takes per rollout (``n_steps`` x ``n_envs``)."""
        return int(self.models[self.agents[0]].n_steps) * self.n_envs

    @property
    def remaining_timesteps(self) -> int:
        """Steps left of the last ``learn()`` call's total (what a resumed run still has to do)."""
        model = self.models[self.agents[0]]
        return max(0, int(getattr(model, "_total_timesteps", 0)) - int(model.num_timesteps))

    def _validate_learners(self, reset_num_timesteps: bool) -> None:
        check_same({a: int(m.n_steps) for a, m in self.models.items()}, "n_steps")
        check_same({a: int(m.n_envs) for a, m in self.models.items()}, "n_envs")
        if not reset_num_timesteps:
            check_same({a: int(m.num_timesteps) for a, m in self.models.items()}, "num_timesteps (to resume)")

    def learn(
        self,
        total_timesteps: int,
        callback: CallbackArg = None,
        progress_bar: bool = False,
        reset_num_timesteps: bool = True,
        log_interval: int = 1,
        tb_log_name: str | None = None,
        checkpoints: CheckpointSchedule | None = None,
        on_interrupt: Callable[[], None] | None = None,
    ) -> IndependentPPO:
        """Train every learner for ``total_timesteps`` of its own steps (as SB3 counts them).

        A team of n agents at T therefore takes n·T agent-steps. To resume a loaded team, pass
        ``reset_num_timesteps=False``: the count then continues from the saved one. A team restored
        with :meth:`from_checkpoint` continues bit for bit with
        ``learn(team.remaining_timesteps, reset_num_timesteps=False)``.

        Each learner draws from its own random stream (:mod:`sb3_pm.agents.multiplexing.streams`);
        the caller's process-wide generators are left as they were
        (:func:`~sb3_pm.agents.training.team_learning.run_team_learning`).

        :param callback: per-agent callbacks: a list, an ``{agent: callback}`` dict or a factory
            ``agent_name -> callback`` (a single callback object only for a one-agent team).
        :param progress_bar: report the team's agent-steps (a tqdm bar on a terminal, a plain line every
            30 s elsewhere; :mod:`sb3_pm.progress`).
        :param tb_log_name: TensorBoard run name prefix; each agent logs to ``<prefix><agent>``.
        :param checkpoints: where and how often to write checkpoints (none by default); a first
            Ctrl-C then checkpoints at the next rollout barrier and raises ``TrainingInterrupted``.
        :param on_interrupt: called on that first Ctrl-C (to tell the user what happens next).
        :raises ValueError: if the learners disagree on ``n_steps``/``n_envs``, or, with ``checkpoints``,
            a hyperparameter has no plain form for the saved team (a Python function as a schedule).
        :raises Exception: the first error a learner raised (the others are stopped cleanly).
        """
        if total_timesteps < 1:
            raise InputError(f"total_timesteps must be positive, got {total_timesteps}")
        self._validate_learners(reset_num_timesteps)
        if checkpoints is not None:
            self.manifest()  # settings with no plain form cannot be checkpointed: refused before training
        self._training_filter()  # the deploy filter is for acting: off while the learners train
        try:
            return run_team_learning(
                self,
                total_timesteps,
                callback,
                progress_bar,
                reset_num_timesteps,
                log_interval,
                tb_log_name,
                checkpoints,
                on_interrupt,
            )
        finally:
            self._apply_deploy_filter()  # on again, whether training ended or failed

    def _rollout_batcher(self) -> RolloutBatcher | None:
        """A batcher for this run's rollout passes, or ``None`` (switched off, learners without the
        hook, or no baton: the passes are stacked only while one learner acts at a time)."""
        models = [self.models[a] for a in self.agents]
        if not (self.batched_rollouts and self.hub.strict_order):
            return None
        if not all(hasattr(m, "rollout_heads_source") for m in models):  # DCBFPPO learners only
            return None
        return RolloutBatcher(self.hub, models)

    # ------------------------------------------------------------ acting
    def learner_for(self, agent: str) -> str:
        """The learner that acts for ``agent``: deploying with another team size ``K'``.

        ``agent_i`` of a ``K'``-agent team uses learner ``agent_(i mod K)`` of this ``K``-agent team:
        with ``K' < K`` the first ``K'`` learners, with ``K' > K`` the learners again in order, so
        ``agent_K`` acts like ``agent_0`` (a copy of a trained agent, which decides from its own map
        as the original does). Names outside ``agent_<i>`` are refused.
        """
        if agent in self.models:
            return agent
        prefix, _, index = agent.rpartition("_")
        if prefix != "agent" or not index.isdigit():
            raise InputError(f"no learner for {agent!r}: this team's agents are {self.agents}")
        return self.agents[int(index) % len(self.agents)]

    def policy_for(self, agent: str) -> Any:
        """The policy of the learner that acts for ``agent`` (:meth:`learner_for`)."""
        return self.models[self.learner_for(agent)].policy

    def on_graph(self, graph: GraphLike, layout: str | None = None) -> Team:
        """This team on ``graph``: itself on its own graph, else its policies rebuilt for ``graph``
        (zero-shot transfer, :mod:`sb3_pm.agents.deployment.transfer`); ``layout``: the env's
        observation layout to act in (``None``: the team's own).

        :raises InputError: if its policies are tied to the training graph's size, saying why.
        """
        return on_graph(self, graph, layout)

    # ---------------------------------------------------------- save / load
    def manifest(self) -> dict[str, Any]:
        """What :meth:`save` writes to ``manifest.json``: the common fields, the agents' names and
        their overrides in plain JSON (:mod:`.learner_record`)."""
        per_agent = {
            agent: plain_hyperparams(v, f"the hyperparams of {agent}") for agent, v in self.per_agent.items()
        }
        return {**super().manifest(), "agents": self.agents, "per_agent": per_agent}

    def model_files(self) -> dict[str, BaseAlgorithm]:
        """One zip per agent, named after it."""
        return {f"{agent}.zip": self.models[agent] for agent in self.agents}

    @classmethod
    def load(
        cls,
        path: str | Path,
        graph: GraphLike | None = None,
        n_envs: int | None = None,
        device: str = "cpu",
        tensorboard_log: str | Path | None = None,
        verbose: int | None = None,
        strict_order: bool = True,
        concurrent_updates: bool = True,
        wait_timeout: float | None = DEFAULT_WAIT_TIMEOUT,
    ) -> IndependentPPO:
        """Load a team saved with :meth:`save` (or the run folder of ``sb3-pm train`` holding it in
        ``team/``), ready to act or to resume training.

        Nothing stored in the folder runs: the learners are built by the constructor from the
        manifest's settings, then given the zips' tensors and counters
        (:mod:`sb3_pm.agents.deployment.model_files`). Further training starts with an env reset.

        :param graph: the graph to run on; ``None`` uses the saved one. It must be the same problem
            (same fingerprint) as the one the team was trained on.
        :param n_envs: env copies for further training (default: the saved number).
        :param concurrent_updates: see the constructor (not saved with a team).
        :param wait_timeout: see the constructor (not saved with a team).
        :raises FileNotFoundError: if the folder, its manifest or an agent's zip is missing.
        :raises OldTeamFormatError: for a team in the old format (``sb3-pm convert-team`` converts it).
        :raises InputError: if ``graph`` is not the graph the team was trained on, or a file is damaged.
        """
        folder, manifest, spec = cls.open_saved(
            path, graph, lambda manifest: [f"{agent}.zip" for agent in manifest["agents"]]
        )
        hyperparams, per_agent = saved_hyperparams(folder / MANIFEST, manifest)
        team = cls(
            spec,
            n_agents=int(manifest["n_agents"]),
            env_kwargs=manifest["env_kwargs"],
            algo=manifest["algo"],
            policy=manifest["policy"],
            n_envs=int(n_envs or manifest["n_envs"]),
            seed=int(manifest["seed"]),
            hyperparams=hyperparams,
            per_agent=per_agent,
            tensorboard_log=tensorboard_log,
            verbose=0 if verbose is None else verbose,
            device=device,
            strict_order=strict_order,
            concurrent_updates=concurrent_updates,
            wait_timeout=wait_timeout,
            deploy_temperature=manifest.get("deploy_temperature"),
            deploy_filter=manifest.get("deploy_filter"),
        )
        return team._restore_saved(folder, device, manifest)  # type: ignore[no-any-return]

    @classmethod
    def from_checkpoint(
        cls,
        path: str | Path,
        device: str = "cpu",
        tensorboard_log: str | Path | None = None,
        verbose: int | None = None,
        **options: Any,
    ) -> IndependentPPO:
        """A team restored from a checkpoint, ready to continue with :meth:`learn_remaining`.

        :param path: a checkpoint folder, a ``checkpoints/`` folder or a run folder holding one (the
            newest intact checkpoint is used).
        :param options: further :meth:`load` arguments (``concurrent_updates``, ``wait_timeout``).
        :raises CheckpointError: if there is no intact checkpoint there.
        """
        checkpoint = find_checkpoint(path)
        team = cls.load(
            checkpoint, device=device, tensorboard_log=tensorboard_log, verbose=verbose, **options
        )
        try:
            restore_state(team, checkpoint)
        except BaseException:
            team.close()
            raise
        team.checkpoint = checkpoint
        return team

    def learn_remaining(
        self, checkpoints: CheckpointSchedule | None = None, **learn_kwargs: Any
    ) -> IndependentPPO:
        """Continue a team restored by :meth:`from_checkpoint` to the end of its interrupted run:
        ``learn(remaining_timesteps, reset_num_timesteps=False)``, writing further checkpoints to
        ``checkpoints`` (which starts from the restored one)."""
        if checkpoints is not None:
            checkpoints.last = self.checkpoint
        if self.remaining_timesteps > 0:
            self.learn(
                self.remaining_timesteps, reset_num_timesteps=False, checkpoints=checkpoints, **learn_kwargs
            )
        return self

    def close(self) -> None:
        """Close the env copies and every learner's logger (TensorBoard files are flushed and their
        writer threads end here, not at interpreter exit)."""
        close_loggers(self.models.values())
        self.hub.close()

    def __repr__(self) -> str:
        return (
            f"IndependentPPO(graph={self.graph.name!r}, n_agents={self.n_agents}, algo={self.algo!r}, "
            f"n_envs={self.n_envs}, num_timesteps={self.num_timesteps if self.models else 0})"
        )


__all__ = [
    "MANIFEST",
    "CheckpointSchedule",
    "EpisodeMetricsCallback",
    "IndependentPPO",
    "TrainingInterrupted",
    "agent_seed",
]
