""":class:`IndependentPPO`: a team of independent SB3 learners, one per agent, sharing nothing.

Each agent is its own SB3 algorithm (``DCBFPPO`` by default, or sb3-contrib's ``MaskablePPO`` or
plain ``PPO``) with its own parameters, buffers and optimizer. They are stepped together through a
:class:`~sb3_pm.agents.multiplexer.ParallelEnvMultiplexer`, each learner in its own thread, in a
fixed turn order, each drawing from its own random stream, so a team run is reproducible from
its seed and can be checkpointed and resumed bit for bit (:mod:`sb3_pm.agents.checkpoints`).

The team implements the :class:`~sb3_pm.baselines.base.Team` interface, so evaluation drives a
learned team exactly as it drives a baseline.

A saved team is a folder::

    team/
      manifest.json     graph name + fingerprint, n_agents, env kwargs, algo, versions
      agent_0.zip ...   one SB3 zip per agent
      graph.graphml     only for graphs that are not presets
"""

from __future__ import annotations

import json
import logging
import os
import pickle
import platform
import zipfile
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.utils import set_random_seed

from sb3_pm.agents.checkpoints import (
    CHECKPOINTS,
    RECORD,
    CheckpointSchedule,
    TrainingInterrupted,
    latest_checkpoint,
    read_record,
    restore_state,
    write_checkpoint,
)
from sb3_pm.agents.multiplexer import (
    ParallelEnvMultiplexer,
    RolloutBarrier,
    learn_concurrently,
    raise_first_error,
)
from sb3_pm.agents.streams import (
    StreamState,
    capture_stream,
    learner_stream_seed,
    load_stream,
    seeded_stream,
)
from sb3_pm.errors import InputError
from sb3_pm.files import write_atomic
from sb3_pm.graphs import PRESETS, GraphLike, GraphSpec, resolve_graph, save_graphml
from sb3_pm.team_interface import Observation, Team
from sb3_pm.zoo.registry import (
    DEFAULT_POLICIES,
    algo_name,
    default_algo,
    resolve_algo,
    resolve_policy_kwargs,
    uses_masks,
)
from sb3_pm.zoo.schedules import SCHEDULE_KEYS, parse_schedule

logger = logging.getLogger(__name__)

MANIFEST = "manifest.json"
MANIFEST_FORMAT = "sb3_pm.team/1"
#: Keys that must be equal for every learner: the multiplexer steps all agents together.
TEAM_KEYS = ("n_steps", "n_envs")
#: Keys the team sets itself; a hyperparameter dict must not hold them.
RESERVED_KEYS = ("env", "policy", "seed", "tensorboard_log", "verbose", "device", "_init_setup_model")

CallbackArg = (
    BaseCallback
    | Sequence[BaseCallback | None]
    | Mapping[str, BaseCallback]
    | Callable[[str], BaseCallback]
    | None
)


class EpisodeMetricsCallback(BaseCallback):
    """Logs the env's episode metrics (``avg_uncertainty``, ``max_neglect`` ...) as ``metrics/<name>``.

    The mean is over this learner's last ``window`` episodes, recorded at each rollout's end, next
    to SB3's ``rollout/ep_rew_mean``.
    """

    def __init__(self, window: int = 100, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.window = window
        self.history: dict[str, deque[float]] = {}

    def _on_step(self) -> bool:
        for info, done in zip(self.locals.get("infos", ()), self.locals.get("dones", ())):
            if done and "metrics" in info:
                for key, value in info["metrics"].items():
                    self.history.setdefault(key, deque(maxlen=self.window)).append(float(value))
        return True

    def _on_rollout_end(self) -> None:
        for key, values in self.history.items():
            if values:
                self.logger.record(f"metrics/{key}", float(np.mean(values)))


def learner_callbacks(model: BaseAlgorithm, callback: BaseCallback | None) -> CallbackList:
    """A team learner's callbacks, in order: an :class:`EpisodeMetricsCallback`, the caller's, the
    estimator fit (for a DCBF-PPO learner with an estimator, which would otherwise attach it
    itself, after everything else), and a :class:`RolloutBarrier` last, so the barrier sees each
    learner with its ``train()`` and estimator fit done."""
    callbacks = list(with_episode_metrics(callback).callbacks)
    if getattr(model, "estimator_update_at", None) and getattr(model.policy, "estimator", None) is not None:
        from sb3_pm.callbacks import EstimatorCallback
        from sb3_pm.ppo_dcbf.ppo_dcbf import _contains_estimator_callback

        if not _contains_estimator_callback(callbacks):
            callbacks.append(EstimatorCallback(update_at=model.estimator_update_at))  # type: ignore[attr-defined]
    callbacks.append(RolloutBarrier())
    return CallbackList(callbacks)


def with_episode_metrics(callback: BaseCallback | list[BaseCallback] | None) -> CallbackList:
    """A learner's callbacks: an :class:`EpisodeMetricsCallback` first, then the caller's (one, a
    list, or none)."""
    callbacks: list[BaseCallback] = [EpisodeMetricsCallback()]
    if isinstance(callback, list):
        callbacks += callback
    elif callback is not None:
        callbacks.append(callback)
    return CallbackList(callbacks)


def _versions() -> dict[str, str]:
    """Versions of the packages a saved team depends on (recorded in the manifest)."""
    import gymnasium
    import pettingzoo
    import stable_baselines3

    from sb3_pm.version import __version__

    versions = {
        "sb3_pm": __version__,
        "stable_baselines3": stable_baselines3.__version__,
        "torch": th.__version__,
        "numpy": np.__version__,
        "gymnasium": gymnasium.__version__,
        "pettingzoo": pettingzoo.__version__,
        "python": platform.python_version(),
    }
    try:
        import sb3_contrib

        versions["sb3_contrib"] = sb3_contrib.__version__
    except ImportError:  # pragma: no cover
        pass
    return versions


def agent_seed(seed: int, index: int) -> int:
    """A distinct, reproducible seed for agent ``index`` of a team seeded with ``seed``.

    Derived through NumPy's ``SeedSequence`` so that agent 1 of seed 0 differs from agent 0 of
    seed 1 (``seed + index`` would make them equal).
    """
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1)[0])


def learn_seed(seed: int, num_timesteps: int) -> int:
    """The seed of the process-wide generators at the start of a ``learn()`` call.

    Distinct from every :func:`agent_seed` (its entropy has three words, theirs two).
    """
    return int(np.random.SeedSequence([int(seed), int(num_timesteps), 1]).generate_state(1)[0])


def _check_same(values: Mapping[str, Any], key: str) -> None:
    if len(set(values.values())) > 1:
        listed = ", ".join(f"{agent}={value}" for agent, value in values.items())
        raise InputError(
            f"every learner of a team must use the same {key} (they are stepped together); got {listed}"
        )


class IndependentPPO(Team):
    """A team of independent PPO-style learners on one persistent-monitoring graph.

    :param graph: a preset name, a ``.graphml`` path or a :class:`GraphSpec`.
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
    """

    name = "ippo"
    omniscient = False

    def __init__(
        self,
        graph: GraphLike,
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
        _init_models: bool = True,
    ) -> None:
        self.graph: GraphSpec = resolve_graph(graph)
        if n_agents < 1:
            raise InputError(f"n_agents must be at least 1, got {n_agents}")
        if n_envs < 1:
            raise InputError(f"n_envs must be at least 1, got {n_envs}")
        self.n_agents = int(n_agents)
        self.n_envs = int(n_envs)
        self.seed = int(seed)
        self.verbose = verbose
        self.device = device
        self.tensorboard_log = None if tensorboard_log is None else str(tensorboard_log)
        self.algo_class: type[BaseAlgorithm]
        self.algo_class, self.algo, self.policy, self.env_kwargs = resolve_learner(algo, policy, env_kwargs)
        for key in ("graph", "n_agents"):
            if key in self.env_kwargs:
                raise InputError(f"env_kwargs must not hold {key!r}: pass it to IndependentPPO itself")
        self.hyperparams = dict(hyperparams or {})
        self.per_agent = {agent: dict(values) for agent, values in (per_agent or {}).items()}

        self.hub = ParallelEnvMultiplexer([self._make_env] * self.n_envs, strict_order=strict_order)
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
            _check_same({agent: kw.get("n_steps", 2048) for agent, kw in kwargs.items()}, "n_steps")
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

    @classmethod
    def from_config(cls, config: Any, graph: GraphLike, seed: int = 0, **kwargs: Any) -> IndependentPPO:
        """A team from a :class:`~sb3_pm.zoo.config.TrainConfig` (an entry of ``zoo/ippo.yml``).

        :param kwargs: further ``IndependentPPO`` arguments (``tensorboard_log``, ``verbose`` ...),
            overriding the config's.
        """
        options = {**config.team_kwargs(), **kwargs}
        return cls(graph, seed=seed, **options)

    # ------------------------------------------------------------ building
    def _make_env(self) -> Any:
        from sb3_pm.envs import persistent_monitoring_v0

        return persistent_monitoring_v0.parallel_env(
            graph=self.graph, n_agents=self.n_agents, **self.env_kwargs
        )

    def agent_kwargs(self, agent: str) -> dict[str, Any]:
        """The algorithm's keyword arguments for ``agent``: shared hyperparameters, then its overrides,
        with ``lin_`` schedules and ``policy_kwargs`` class names resolved."""
        merged = {**self.hyperparams, **self.per_agent.get(agent, {})}
        for key in RESERVED_KEYS:
            if key in merged and key != "policy":
                raise InputError(
                    f"hyperparameter {key!r} ({agent}) is set by the team; pass it to IndependentPPO"
                )
        if "n_envs" in merged:
            if int(merged.pop("n_envs")) != self.n_envs:
                raise InputError(
                    f"every learner of a team must use the same n_envs; {agent} asks for a different one "
                    f"than the team's {self.n_envs}"
                )
        return resolve_hyperparams(merged)

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

    def _learner_streams(self, reset_num_timesteps: bool) -> list[StreamState]:
        """Each learner's random stream for a ``learn()`` call: the checkpoint's when resuming one,
        else fresh ones seeded from (seed, step count, learner)."""
        if not reset_num_timesteps and self._resume_streams is not None:
            streams = self._resume_streams
        else:
            streams = [
                seeded_stream(learner_stream_seed(self.seed, self.num_timesteps, i))
                for i in range(self.n_agents)
            ]
        self._resume_streams = None
        return streams

    def _at_barrier(self, checkpoints: CheckpointSchedule | None) -> str | None:
        """The multiplexer's ``on_sync`` hook: write a checkpoint when one is due; after an
        interrupt, write one and stop the team."""
        if checkpoints is None:
            return None
        rollouts = self.num_timesteps // self.rollout_size
        if not checkpoints.due(rollouts, self.hub.stop_requested):
            return None
        folder = write_checkpoint(self, checkpoints, rollouts)
        logger.info("checkpoint %s written", folder)
        if self.hub.stop_requested:
            return f"interrupted; checkpoint {folder} saved"
        return None

    def _validate_learners(self, reset_num_timesteps: bool) -> None:
        _check_same({a: int(m.n_steps) for a, m in self.models.items()}, "n_steps")
        _check_same({a: int(m.n_envs) for a, m in self.models.items()}, "n_envs")
        if not reset_num_timesteps:
            _check_same(
                {a: int(m.num_timesteps) for a, m in self.models.items()}, "num_timesteps (to resume)"
            )

    def _callbacks(self, callback: CallbackArg) -> list[BaseCallback | None]:
        if callback is None:
            return [None] * self.n_agents
        if isinstance(callback, BaseCallback):
            if self.n_agents == 1:
                return [callback]
            raise TypeError(
                "one callback object cannot serve several learners; pass a list (one per agent), a "
                "{agent: callback} dict or a factory agent_name -> callback"
            )
        if isinstance(callback, Mapping):
            return [callback.get(agent) for agent in self.agents]
        if callable(callback):
            return [callback(agent) for agent in self.agents]
        callbacks = list(callback)
        if len(callbacks) != self.n_agents:
            raise InputError(f"got {len(callbacks)} callbacks for {self.n_agents} agents")
        return callbacks

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

        Each learner draws from its own random stream, seeded from the team seed, the step count and
        its index (:mod:`sb3_pm.agents.streams`); the caller's process-wide generators are left as
        they were.

        :param callback: per-agent callbacks: a list, an ``{agent: callback}`` dict or a factory
            ``agent_name -> callback`` (a single callback object only for a one-agent team).
        :param progress_bar: report the team's agent-steps (a tqdm bar on a terminal, a plain line every
            30 s elsewhere; :mod:`sb3_pm.progress`).
        :param tb_log_name: TensorBoard run name prefix; each agent logs to ``<prefix><agent>``.
        :param checkpoints: where and how often to write checkpoints (none by default). With
            checkpoints, a first Ctrl-C lets the team run to the next rollout barrier, writes a
            checkpoint there and raises :class:`~sb3_pm.agents.checkpoints.TrainingInterrupted`; a
            second one stops at once (the last periodic checkpoint stays).
        :param on_interrupt: called on that first Ctrl-C (to tell the user what happens next).
        :raises ValueError: if the learners disagree on ``n_steps``/``n_envs``.
        :raises Exception: the first error a learner raised (the others are stopped cleanly).
        """
        if total_timesteps < 1:
            raise InputError(f"total_timesteps must be positive, got {total_timesteps}")
        self._validate_learners(reset_num_timesteps)
        if not reset_num_timesteps and any(m._last_obs is None for m in self.models.values()):
            # All learners must reset together (the multiplexer steps them as one).
            for model in self.models.values():
                model._last_obs = None
        # Whatever ran since construction (another team, an evaluation) must not leak into this
        # run: with the baton, each learner draws from its own stream, seeded here, so the run is a
        # function of (seed, num_timesteps, parameters) alone. Without it, a shared reseed.
        caller_stream = capture_stream()
        if self.hub.strict_order:
            self.hub.set_streams(self._learner_streams(reset_num_timesteps))
        else:
            self.hub.set_streams(None)
            set_random_seed(learn_seed(self.seed, self.num_timesteps))
        user_callbacks = self._callbacks(callback)
        learn_kwargs = []
        for agent, user in zip(self.agents, user_callbacks):
            learn_kwargs.append(
                {
                    "total_timesteps": int(total_timesteps),
                    "callback": learner_callbacks(self.models[agent], user),
                    "log_interval": log_interval,
                    "tb_log_name": f"{tb_log_name or ''}{agent}",
                    "reset_num_timesteps": reset_num_timesteps,
                    "progress_bar": False,
                }
            )
        bar = None
        if progress_bar:
            from sb3_pm.progress import progress_bar as make_progress

            rollout = self.models[self.agents[0]].n_steps * self.n_envs
            rollouts = -(-int(total_timesteps) // rollout)
            bar = make_progress(
                rollouts * rollout * self.n_agents, f"{self.algo} x{self.n_agents}", unit="agent-step"
            )
            self.hub.on_round = bar.update
        self.hub.on_sync = lambda: self._at_barrier(checkpoints)
        try:
            errors = learn_concurrently(
                [self.models[a] for a in self.agents],
                self.hub,
                learn_kwargs,
                graceful_interrupt=checkpoints is not None,
                on_interrupt=on_interrupt,
            )
        except KeyboardInterrupt:
            if checkpoints is not None and self.hub.stopped is not None and checkpoints.last is not None:
                raise TrainingInterrupted(checkpoints.last) from None
            raise
        finally:
            self.hub.on_round = None
            self.hub.on_sync = None
            load_stream(caller_stream)
            if bar is not None:
                bar.close()
        raise_first_error(errors)
        if self.hub.aborted is not None:
            logger.warning("team training ended early: %s", self.hub.aborted)
        return self

    # ------------------------------------------------------------ acting
    def reset(self, env: Any, seed: int | None = None) -> None:
        """Start an episode on ``env``; checks it is the graph the team was built for.

        With a ``seed``, torch's global generator is seeded too, so stochastic
        (``deterministic=False``) actions are reproducible.
        """
        super().reset(env, seed)
        other = getattr(getattr(env, "unwrapped", env), "graph", None)
        if isinstance(other, GraphSpec):
            check_same_graph(self.graph, other)
        if seed is not None:
            th.manual_seed(seed)

    def predict(self, observations: dict[str, Observation], deterministic: bool = True) -> dict[str, int]:
        """One destination node per agent in ``observations``, each from its own learner."""
        actions: dict[str, int] = {}
        for agent, obs in observations.items():
            model = self.models[agent]
            if uses_masks(type(model)):
                action, _ = model.predict(
                    obs, deterministic=deterministic, action_masks=np.asarray(obs["action_mask"], dtype=bool)
                )
            else:
                action, _ = model.predict(obs, deterministic=deterministic)
            actions[agent] = int(np.asarray(action).reshape(-1)[0])
        return actions

    # ---------------------------------------------------------- save / load
    def manifest(self) -> dict[str, Any]:
        """What :meth:`save` writes to ``manifest.json``."""
        return {**team_manifest(self, MANIFEST_FORMAT), "agents": self.agents}

    def save(self, path: str | Path, overwrite: bool = False) -> Path:
        """Save the team to the folder ``path`` (created if needed).

        :raises FileExistsError: if ``path`` already holds a team and ``overwrite`` is False.
        """
        folder = Path(path)
        if folder.exists() and not folder.is_dir():
            raise FileExistsError(f"{folder} exists and is not a folder")
        if folder.is_dir() and not overwrite and ((folder / MANIFEST).exists() or any(folder.glob("*.zip"))):
            raise FileExistsError(f"{folder} already holds a saved team; pass overwrite=True to replace it")
        folder.mkdir(parents=True, exist_ok=True)
        for agent in self.agents:
            save_model_atomic(self.models[agent], folder / f"{agent}.zip")
        save_graph_copy(self.graph, folder)
        write_manifest(folder, self.manifest())  # last: a folder with a manifest holds a whole team
        return folder

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
        custom_objects: dict[str, Any] | None = None,
        force_reset: bool = True,
    ) -> IndependentPPO:
        """Load a team saved with :meth:`save` (or the run folder of ``sb3-pm train`` holding it in
        ``team/``), ready to act or to resume training.

        :param graph: the graph to run on; ``None`` uses the saved one. It must be the same problem
            (same fingerprint) as the one the team was trained on.
        :param n_envs: env copies for further training (default: the saved number).
        :param force_reset: start further training with an env reset (SB3's default); False keeps the
            saved last observations, for :meth:`from_checkpoint`, which restores the env copies too.
        :raises FileNotFoundError: if the folder, its manifest or an agent's zip is missing.
        :raises ValueError: if ``graph`` is not the graph the team was trained on.
        """
        folder = Path(path)
        if not (folder / MANIFEST).exists() and (folder / "team" / MANIFEST).exists():
            folder = folder / "team"  # a run folder written by ``sb3-pm train``
        manifest_path = folder / MANIFEST
        if not folder.is_dir():
            raise FileNotFoundError(f"no saved team at {folder} (not a folder)")
        if not manifest_path.exists():
            raise FileNotFoundError(f"{folder} is not a saved team: {MANIFEST} is missing")
        manifest = read_manifest(folder)
        spec = graph_for_saved_team(folder, manifest, graph)
        zips = {agent: folder / f"{agent}.zip" for agent in manifest["agents"]}
        missing = [str(p) for p in zips.values() if not p.exists()]
        if missing:
            raise FileNotFoundError(f"saved team {folder} is incomplete: missing {', '.join(missing)}")
        team = cls(
            spec,
            n_agents=int(manifest["n_agents"]),
            env_kwargs=manifest["env_kwargs"],
            algo=manifest["algo"],
            policy=manifest["policy"],
            n_envs=int(n_envs or manifest["n_envs"]),
            seed=int(manifest["seed"]),
            tensorboard_log=tensorboard_log,
            verbose=0 if verbose is None else verbose,
            device=device,
            strict_order=strict_order,
            _init_models=False,
        )
        for i, agent in enumerate(team.agents):
            model = load_model_file(
                team.algo_class,
                zips[agent],
                env=team.hub.vec_envs[i],
                device=device,
                custom_objects=custom_objects,
                force_reset=force_reset,
            )
            if tensorboard_log is not None:
                model.tensorboard_log = str(tensorboard_log)
            if verbose is not None:
                model.verbose = verbose
            team.models[agent] = model
        return team

    @classmethod
    def from_checkpoint(
        cls,
        path: str | Path,
        device: str = "cpu",
        tensorboard_log: str | Path | None = None,
        verbose: int | None = None,
    ) -> IndependentPPO:
        """A team restored from a checkpoint, ready to continue with
        ``learn(team.remaining_timesteps, reset_num_timesteps=False)``.

        :param path: a checkpoint folder, a ``checkpoints/`` folder or a run folder holding one (the
            newest intact checkpoint is used).
        :raises CheckpointError: if there is no intact checkpoint there.
        """
        folder = Path(path)
        if (folder / RECORD).is_file():
            read_record(folder)  # checks every file against its checksum
            checkpoint = folder
        else:
            parent = folder / CHECKPOINTS if (folder / CHECKPOINTS).is_dir() else folder
            checkpoint, _ = latest_checkpoint(parent)
        team = cls.load(
            checkpoint, device=device, tensorboard_log=tensorboard_log, verbose=verbose, force_reset=False
        )
        restore_state(team, checkpoint)
        team.checkpoint = checkpoint
        return team

    def close(self) -> None:
        self.hub.close()

    def __repr__(self) -> str:
        return (
            f"IndependentPPO(graph={self.graph.name!r}, n_agents={self.n_agents}, algo={self.algo!r}, "
            f"n_envs={self.n_envs}, num_timesteps={self.num_timesteps if self.models else 0})"
        )


def resolve_learner(
    algo: str | type | None, policy: str | type | None, env_kwargs: Mapping[str, Any] | None
) -> tuple[Any, str, str | type, dict[str, Any]]:
    """The algorithm class and its registry name, the policy (the algorithm's default when None),
    and the env kwargs a learner of that algorithm needs.

    ``algo=None`` picks ``dcbf_ppo`` when importable. An algorithm without action masks may pick
    any node, and the env's default ``illegal_action="raise"`` would end training: such learners
    get ``illegal_action="stay"`` unless the caller set it.
    """
    algo = algo if algo is not None else default_algo()
    algo_class = resolve_algo(algo) if isinstance(algo, str) else algo
    name = algo if isinstance(algo, str) else algo_name(algo)
    policy = policy if policy is not None else DEFAULT_POLICIES.get(name, "MultiInputPolicy")
    kwargs = dict(env_kwargs or {})
    if not uses_masks(algo_class):
        kwargs.setdefault("illegal_action", "stay")
    return algo_class, name, policy, kwargs


def resolve_hyperparams(hyperparams: Mapping[str, Any]) -> dict[str, Any]:
    """Config values -> algorithm keyword arguments: ``lin_`` schedules become SB3 schedules and
    ``policy_kwargs`` class names become classes."""
    resolved = dict(hyperparams)
    for key in SCHEDULE_KEYS:
        if key in resolved:
            resolved[key] = parse_schedule(resolved[key], key)
    if "policy_kwargs" in resolved:
        resolved["policy_kwargs"] = resolve_policy_kwargs(resolved["policy_kwargs"])
    return resolved


def team_manifest(team: Any, manifest_format: str) -> dict[str, Any]:
    """The manifest fields every saved team kind records (graph, sizes, env, algorithm, versions)."""
    return {
        "format": manifest_format,
        "graph": graph_record(team.graph),
        "n_agents": team.n_agents,
        "env_kwargs": team.env_kwargs,
        "algo": team.algo,
        "policy": team.policy if isinstance(team.policy, str) else team.policy.__name__,
        "n_envs": team.n_envs,
        "seed": team.seed,
        "num_timesteps": team.num_timesteps,
        "versions": _versions(),
    }


def graph_record(graph: GraphSpec) -> dict[str, Any]:
    """How a saved team's manifest names its graph."""
    return {
        "name": graph.name,
        "fingerprint": graph.fingerprint,
        "n_nodes": graph.n_nodes,
        "n_targets": graph.n_targets,
    }


def save_graph_copy(graph: GraphSpec, folder: Path) -> None:
    """Keep a GraphML copy next to a saved team, unless the graph is a preset (rebuilt by name)."""
    if not (graph.name in PRESETS and resolve_graph(graph.name).same_problem(graph)):
        save_graphml(graph, folder / "graph.graphml", overwrite=True)


def save_model_atomic(model: Any, path: Path) -> None:
    """``model.save`` to a temporary name beside ``path``, then a rename: an interrupted save
    leaves the previous file or the new one, never a truncated zip."""
    temporary = path.with_name(f".{path.stem}.tmp.zip")  # SB3 keeps a .zip suffix as given
    model.save(temporary)
    os.replace(temporary, path)


def load_model_file(algo_class: type[BaseAlgorithm], path: Path, **kwargs: Any) -> Any:
    """``algo_class.load(path, **kwargs)``, with a corrupt or foreign file as one ``ValueError``
    that names it (a valid zip holding a damaged ``policy.pth`` raised torch's RuntimeError).

    :raises ValueError: if the file cannot be read as a model of ``algo_class``.
    """
    try:
        return algo_class.load(path, **kwargs)
    except (RuntimeError, OSError, EOFError, KeyError, zipfile.BadZipFile, pickle.UnpicklingError) as error:
        if isinstance(error, FileNotFoundError):
            raise
        reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise InputError(
            f"{path} cannot be loaded, the file is damaged or not a saved model ({reason})"
        ) from error


def write_manifest(folder: Path, manifest: Mapping[str, Any]) -> None:
    """Write ``manifest.json`` atomically (temporary file, then rename)."""
    write_atomic(folder / MANIFEST, json.dumps(manifest, indent=2, sort_keys=True) + "\n")


def read_manifest(folder: Path) -> dict[str, Any]:
    """A saved team's ``manifest.json``.

    :raises FileNotFoundError: if it is missing. :raises ValueError: if it is not valid JSON.
    """
    path = folder / MANIFEST
    if not path.exists():
        raise FileNotFoundError(f"{folder} is not a saved team: {MANIFEST} is missing")
    try:
        return dict(json.loads(path.read_text()))
    except json.JSONDecodeError as error:
        raise InputError(f"{path} is not valid JSON: {error}") from error


def graph_for_saved_team(folder: Path, manifest: Mapping[str, Any], graph: GraphLike | None) -> GraphSpec:
    """The graph to run a saved team on: ``graph`` if given, else the saved copy or preset.

    :raises ValueError: if it is not the problem the team was trained on (naming both graphs).
    """
    saved = manifest["graph"]
    if graph is None:
        graph_file = folder / "graph.graphml"
        spec = resolve_graph(graph_file if graph_file.exists() else saved["name"])
    else:
        spec = resolve_graph(graph)
    if spec.fingerprint != saved["fingerprint"]:
        raise InputError(
            f"the team in {folder} was trained on graph {saved['name']!r} "
            f"(fingerprint {saved['fingerprint']}), "
            f"not on graph {spec.name!r} (fingerprint {spec.fingerprint})"
        )
    return spec


def check_same_graph(expected: GraphSpec, actual: GraphSpec) -> None:
    """Raise a ``ValueError`` naming both graphs if they are not the same problem."""
    if expected.fingerprint != actual.fingerprint:
        raise InputError(
            f"the team was trained on graph {expected.name!r} (fingerprint {expected.fingerprint}), "
            f"not on graph {actual.name!r} (fingerprint {actual.fingerprint})"
        )


__all__ = [
    "CheckpointSchedule",
    "EpisodeMetricsCallback",
    "IndependentPPO",
    "TrainingInterrupted",
    "agent_seed",
    "check_same_graph",
    "learn_seed",
    "load_model_file",
    "save_model_atomic",
    "write_manifest",
]
