"""The persistent-monitoring env as a BenchMARL task, and a trained BenchMARL policy as a team.

Needs the optional extra ``benchmarl`` (``pip install "sb3_pm[benchmarl]"``), which brings
BenchMARL, TorchRL and TensorDict. The task trains BenchMARL's algorithms (MAPPO, IPPO, QMIX, ...)
on :class:`~sb3_pm.integrations.flat_env.FlatMonitoringEnv`, the monitoring env with one flat
observation vector per agent:

- **Observation.** Each agent's mental map, flattened and scaled to ``[0, 1]``
  (:class:`~sb3_pm.integrations.flat_env.Flattener`); no global state, so MAPPO's critic sees
  the agents' observations side by side.
- **Action masks.** The reachable set reaches BenchMARL through the task's ``action_mask`` spec
  (TorchRL's ``(group, "action_mask")``), and the policies sample from a masked categorical: an
  agent only ever asks for a legal move.
- **Failures.** With ``failures`` or ``failure_rate`` in the env settings, TorchRL's alive mask
  (``use_mask``: ``(group, "mask")``) marks the failed agents and an episode ends when every
  agent is done. BenchMARL's losses do not read that mask: a failed agent's zero observations
  still enter the updates.
- **Settings.** By default the env of the project's training config as the peer runs measured it
  (``zoo/ippo_split.yml``'s entry for the graph, the default before planned territories: its
  reward terms, ``graph_knowledge`` and ``max_cycles``); keywords override them.

Usage::

    from sb3_pm.integrations.benchmarl_task import monitoring_task, BenchMARLTeam
    task = monitoring_task("paper-50", n_agents=4)          # a BenchMARL TaskClass
    experiment = Experiment(task=task, algorithm_config=MappoConfig.get_from_yaml(), ...)
    experiment.run()
    team = BenchMARLTeam.from_experiment(experiment, task, name="mappo")
    evaluate(team, "paper-50", episodes=10, seed=7)

``benchmarks/benchmarl_peers.py`` trains and evaluates the peers this way.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from benchmarl.environments.common import Task
from benchmarl.environments.pettingzoo.common import PettingZooClass
from tensordict import TensorDict
from torchrl.envs import EnvBase, PettingZooWrapper
from torchrl.envs.utils import ExplorationType, set_exploration_type

from sb3_pm.errors import InputError
from sb3_pm.integrations.flat_env import Flattener, flat_parallel_env
from sb3_pm.team_interface import Observation, Team, without_caller_keys

#: The group TorchRL's wrapper forms from the agent names (``agent_0`` to ``agent_{n-1}``).
GROUP = "agent"


#: The training config whose env the task takes by default: the default before planned territories,
#: the env of the peer runs of research/records/benchmarl_peers (on paper-50 the default's env has
#: since added planned territories, the targets known and the territory rule's move as inputs).
TASK_CONFIG = "ippo_split"


def default_env_settings(graph: str) -> dict[str, Any]:
    """The env settings of the project's training config as the peers measured it
    (``zoo/ippo_split.yml``, :data:`TASK_CONFIG`) for ``graph``: its ``env_kwargs``
    (``max_cycles``, ``reward``, ``graph_knowledge``, ...).

    :raises ConfigError: for a graph that config cannot place (see :func:`sb3_pm.zoo.load_config`).
    """
    from sb3_pm.zoo import load_config

    return dict(load_config(TASK_CONFIG, graph).env_kwargs)


def _uses_failures(env_kwargs: dict[str, Any]) -> bool:
    return bool(env_kwargs.get("failures")) or float(env_kwargs.get("failure_rate") or 0.0) > 0.0


def make_torchrl_env(config: dict[str, Any], seed: int | None, device: Any = "cpu") -> EnvBase:
    """The TorchRL env of a task ``config`` (``graph``, ``n_agents``, ``max_cycles``,
    ``adjacency`` and the monitoring env's arguments): the flat view in TorchRL's PettingZoo wrapper.

    A module-level function (not a lambda), so that the env factory pickles.
    """
    settings = dict(config)
    failures = _uses_failures(settings)
    env = flat_parallel_env(**settings)
    return PettingZooWrapper(
        env=env,
        categorical_actions=True,
        device=device,
        seed=seed,
        return_state=False,
        use_mask=failures,
        done_on_any=False,
    )


class MonitoringTaskClass(PettingZooClass):
    """BenchMARL's ``TaskClass`` for persistent monitoring (see the module docstring); its
    ``config`` holds the env's arguments."""

    def get_env_fun(
        self, num_envs: int, continuous_actions: bool, seed: int | None, device: Any
    ) -> Callable[[], EnvBase]:
        return functools.partial(make_torchrl_env, dict(self.config), seed, device)

    def supports_continuous_actions(self) -> bool:
        return False

    def supports_discrete_actions(self) -> bool:
        return True

    def has_state(self) -> bool:
        return False

    def has_render(self, env: EnvBase) -> bool:
        return False

    def max_steps(self, env: EnvBase) -> int:
        return int(self.config.get("max_cycles", 500))

    @staticmethod
    def env_name() -> str:
        return "sb3_pm"


class MonitoringTask(Task):
    """BenchMARL's task enum for persistent monitoring: one task, configured by
    :func:`monitoring_task` (``get_task(config)`` takes the same settings as a dict)."""

    PERSISTENT_MONITORING = None

    @staticmethod
    def associated_class() -> type[MonitoringTaskClass]:
        return MonitoringTaskClass

    def get_from_yaml(self, path: str | None = None) -> MonitoringTaskClass:
        """The default task (``paper-50``, 4 agents, the training config's env), whatever ``path``
        says: the task ships no YAML file."""
        return monitoring_task()


def monitoring_task(
    graph: str = "paper-50",
    n_agents: int = 4,
    max_cycles: int | None = None,
    adjacency: bool | None = None,
    **env_kwargs: Any,
) -> MonitoringTaskClass:
    """A BenchMARL task on ``graph`` (a preset name or a ``.graphml`` path) with ``n_agents``.

    :param max_cycles: episode length; ``None``: the training config's (500).
    :param adjacency: include the known adjacency in the observation vector; ``None``: only
        when the graph is discovered (:class:`~sb3_pm.integrations.flat_env.FlatMonitoringEnv`).
    :param env_kwargs: the monitoring env's arguments, over the training config's
        (:func:`default_env_settings`).
    :raises InputError: for ``n_agents < 1``, or settings the env refuses (checked by building it once).
    """
    if not isinstance(graph, str):
        raise InputError(f"graph must be a preset name or a .graphml path, got {type(graph).__name__}")
    if n_agents < 1:
        raise InputError(f"n_agents must be at least 1, got {n_agents}")
    settings = {**default_env_settings(graph), **env_kwargs}
    if max_cycles is not None:
        settings["max_cycles"] = int(max_cycles)
    config = {"graph": graph, "n_agents": int(n_agents), "adjacency": adjacency, **settings}
    flat_parallel_env(**config).close()  # one-line errors now, not inside BenchMARL's collectors
    return MonitoringTaskClass(name="PERSISTENT_MONITORING", config=config)


#: BenchMARL's algorithms the peers use, by the name on the command line.
ALGORITHMS = ("mappo", "ippo", "qmix")

#: The project's PPO settings (``zoo/ippo.yml``) where BenchMARL has the same knob: one rollout
#: of 250 steps from each of 2 envs per update, 5 epochs of 2 minibatches of 250 frames, and the
#: loss coefficients. Everything else stays BenchMARL's default.
PPO_SCHEDULE = {"frames_per_batch": 500, "n_envs": 2, "minibatch_size": 250, "minibatch_iters": 10}
PPO_LOSS = {"clip_epsilon": 0.2, "entropy_coef": 0.01, "lmbda": 0.95}
#: QMIX (off-policy): the same 500-frame collections, 100 optimizer steps of 128 frames after each.
QMIX_SCHEDULE = {"frames_per_batch": 500, "n_envs": 2, "optimizer_steps": 100, "batch_size": 128}


def experiment_config(
    frames: int, lr: float, folder: str, gamma: float = 0.99, share_policy_params: bool = True
) -> Any:
    """BenchMARL's ``ExperimentConfig`` for a peer run: ``frames`` env steps (each one frame
    for the whole team, so every agent sees ``frames`` transitions, as a learner of the
    project's team does with ``n_timesteps = frames``), learning rate ``lr``, the project's
    rollout schedule (:data:`PPO_SCHEDULE`, :data:`QMIX_SCHEDULE`) and gradient clip (norm 0.5),
    CSV logs and a final checkpoint in ``folder``, no BenchMARL evaluation (the project's own
    harness evaluates the trained team). ``share_policy_params``: one actor for the whole team
    (BenchMARL's default), or one per agent, as the project's independent learners have.

    :raises InputError: ``frames`` not a positive multiple of 500, or ``lr`` not positive.
    """
    from benchmarl.experiment import ExperimentConfig

    per_batch = PPO_SCHEDULE["frames_per_batch"]
    if frames < per_batch or frames % per_batch:
        raise InputError(f"frames must be a positive multiple of {per_batch}, got {frames}")
    if not lr > 0:
        raise InputError(f"lr must be positive, got {lr}")
    config = ExperimentConfig.get_from_yaml()
    config.max_n_frames = int(frames)
    config.lr = float(lr)
    config.gamma = float(gamma)
    config.share_policy_params = bool(share_policy_params)
    config.clip_grad_norm, config.clip_grad_val = True, 0.5
    config.on_policy_collected_frames_per_batch = PPO_SCHEDULE["frames_per_batch"]
    config.on_policy_n_envs_per_worker = PPO_SCHEDULE["n_envs"]
    config.on_policy_minibatch_size = PPO_SCHEDULE["minibatch_size"]
    config.on_policy_n_minibatch_iters = PPO_SCHEDULE["minibatch_iters"]
    config.off_policy_collected_frames_per_batch = QMIX_SCHEDULE["frames_per_batch"]
    config.off_policy_n_envs_per_worker = QMIX_SCHEDULE["n_envs"]
    config.off_policy_n_optimizer_steps = QMIX_SCHEDULE["optimizer_steps"]
    config.off_policy_train_batch_size = QMIX_SCHEDULE["batch_size"]
    config.off_policy_memory_size = int(frames)
    config.evaluation, config.render = False, False
    config.loggers, config.create_json = ["csv"], False
    config.save_folder = str(folder)
    config.checkpoint_interval, config.checkpoint_at_end = 0, True
    return config


def algorithm_config(name: str, share_critic: bool = True) -> Any:
    """BenchMARL's config of algorithm ``name`` (:data:`ALGORITHMS`): its YAML defaults, with the
    project's PPO loss settings (:data:`PPO_LOSS`) for ``mappo`` and ``ippo``, and for those two
    one critic for the team (``share_critic``, BenchMARL's default) or one per agent.

    :raises InputError: an unknown name.
    """
    from benchmarl.algorithms import IppoConfig, MappoConfig, QmixConfig

    classes = {"mappo": MappoConfig, "ippo": IppoConfig, "qmix": QmixConfig}
    if name not in classes:
        raise InputError(f"unknown algorithm {name!r}; choose from {', '.join(ALGORITHMS)}")
    config = classes[name].get_from_yaml()
    if name in ("mappo", "ippo"):
        for key, value in PPO_LOSS.items():
            setattr(config, key, value)
        config.share_param_critic = bool(share_critic)
    return config


def make_experiment(
    algorithm: str,
    task: MonitoringTaskClass,
    seed: int,
    frames: int,
    lr: float,
    folder: str,
    share_policy_params: bool = True,
) -> Any:
    """A BenchMARL ``Experiment`` of ``algorithm`` on ``task`` (:func:`experiment_config`,
    :func:`algorithm_config`), with BenchMARL's default MLP (two layers of 256, tanh) for the
    actor and, where it has one, the critic; ``share_policy_params=False`` gives each agent its own
    actor and critic (:func:`experiment_config`, :func:`algorithm_config`)."""
    from benchmarl.experiment import Experiment
    from benchmarl.models.mlp import MlpConfig

    return Experiment(
        task=task,
        algorithm_config=algorithm_config(algorithm, share_critic=share_policy_params),
        model_config=MlpConfig.get_from_yaml(),
        critic_model_config=MlpConfig.get_from_yaml(),
        seed=int(seed),
        config=experiment_config(frames, lr, folder, share_policy_params=share_policy_params),
    )


class BenchMARLTeam(Team):
    """A trained BenchMARL policy acting as a :class:`~sb3_pm.team_interface.Team`.

    Each agent's action comes from its own observation (flattened as in training) and its own
    action mask, so the team is as decentralized as the policy's actor: with a shared actor
    (BenchMARL's default), every agent runs the same network on its own input.

    :param policy: the BenchMARL collection policy (``experiment.policy``), reading
        ``(GROUP, "observation")`` and ``(GROUP, "action_mask")`` and writing ``(GROUP, "action")``.
    :param task_config: the task's config (:func:`monitoring_task`), for the env it acts in.
    :param name: the name in reports.
    """

    resizable = False

    def __init__(self, policy: Any, task_config: dict[str, Any], name: str = "benchmarl") -> None:
        self.policy = policy
        self.name = name
        self.task_config = dict(task_config)
        self.n_agents = int(self.task_config["n_agents"])
        self._graph = self.task_config["graph"]
        self._adjacency = self.task_config.get("adjacency")
        self._flattener: Flattener | None = None
        self._agents = [f"agent_{i}" for i in range(self.n_agents)]

    @classmethod
    def from_experiment(
        cls, experiment: Any, task: MonitoringTaskClass, name: str = "benchmarl"
    ) -> BenchMARLTeam:
        """The team of a trained ``experiment`` on ``task``."""
        return cls(experiment.policy, task.config, name=name)

    def env_settings(self) -> dict[str, Any]:
        settings = without_caller_keys(self.task_config)
        settings.pop("adjacency", None)
        return settings

    def default_graph(self) -> Any:
        return self._graph

    def reset(self, env: Any, seed: int | None = None) -> None:
        super().reset(env, seed)
        base = env.unwrapped
        if len(base.possible_agents) != self.n_agents:
            raise InputError(
                f"{self.name!r} was trained for {self.n_agents} agents, not {len(base.possible_agents)}"
            )
        adjacency = self._adjacency
        if adjacency is None:
            adjacency = getattr(base, "graph_knowledge", "discovered") != "known"
        self._flattener = Flattener(env.observation_space(base.possible_agents[0]), adjacency)
        if seed is not None:  # a sampled action draws from torch's generator
            torch.manual_seed(seed)

    def predict_dict(
        self, observations: dict[str, Observation], deterministic: bool = True
    ) -> dict[str, int]:
        flattener = self._flattener
        if flattener is None:
            raise InputError(f"{self.name!r}: call reset(env) before predict_dict")
        vectors = np.zeros((self.n_agents, flattener.size), dtype=np.float32)
        masks = np.ones((self.n_agents, flattener.n_nodes), dtype=bool)
        present = [agent for agent in self._agents if agent in observations]
        for agent in present:
            i = self._agents.index(agent)
            vectors[i] = flattener(observations[agent])
            masks[i] = np.asarray(observations[agent]["action_mask"], dtype=bool)
        data = TensorDict(
            {
                GROUP: TensorDict(
                    {"observation": torch.from_numpy(vectors), "action_mask": torch.from_numpy(masks)},
                    batch_size=[self.n_agents],
                )
            },
            batch_size=[],
        )
        mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
        with torch.no_grad(), set_exploration_type(mode):
            actions = self.policy(data).get((GROUP, "action"))
        return {agent: int(actions[self._agents.index(agent)]) for agent in present}


__all__ = [
    "ALGORITHMS",
    "GROUP",
    "PPO_LOSS",
    "PPO_SCHEDULE",
    "QMIX_SCHEDULE",
    "TASK_CONFIG",
    "BenchMARLTeam",
    "MonitoringTask",
    "MonitoringTaskClass",
    "algorithm_config",
    "default_env_settings",
    "experiment_config",
    "make_experiment",
    "make_torchrl_env",
    "monitoring_task",
]
