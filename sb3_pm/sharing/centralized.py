""":class:`CentralizedPPO`: the paper's centralized comparison, as configuration of the same model.

The ``centralized`` algorithm of docs/METHOD.md has one shared mental map (the union of every agent's
observations), one shared estimator and one network acting for every agent. Here that is:

- the environment option ``shared_map=True`` (every agent's map receives the team's observations);
- parameter sharing through SuperSuit (:func:`make_parameter_sharing_vec_env`): one model, one
  estimator, trained on every agent's transitions;
- the same algorithm and policy classes as the decentralized team (``DCBFPPO`` + ``DCBFPolicy`` by
  default), with the same hyperparameters from the same config file.

Budgets are counted as for :class:`~sb3_pm.agents.training.team.IndependentPPO`: ``learn(T)`` gives the
team ``n_agents * T`` agent-steps, so both teams see the same amount of experience.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from stable_baselines3.common.utils import set_random_seed

from sb3_pm.agents.deployment.saved_teams import MANIFEST
from sb3_pm.agents.training.learned_team import LearnedTeam
from sb3_pm.agents.training.learner_callbacks import close_loggers, with_episode_metrics
from sb3_pm.agents.training.learner_record import saved_hyperparams
from sb3_pm.agents.training.learners import learn_seed, resolve_hyperparams
from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphFamily, GraphLike, GraphSpec
from sb3_pm.policies.settings import check_advice_source
from sb3_pm.sharing.supersuit_vec_env import make_parameter_sharing_vec_env

MANIFEST_FORMAT = "sb3_pm.centralized/2"
#: The format before, loadable only by unpickling: refused (``sb3-pm convert-team`` converts it).
OLD_FORMATS = ("sb3_pm.centralized/1",)
MODEL_FILE = "shared.zip"


class CentralizedPPO(LearnedTeam):
    """One shared map, estimator and network acting for the whole team.

    :param graph: a preset name, a ``.graphml`` path or a :class:`GraphSpec`.
    :param n_agents: team size.
    :param env_kwargs: environment options (``shared_map`` is forced on).
    :param algo: as for ``IndependentPPO`` (default ``dcbf_ppo`` when importable).
    :param policy: the policy; ``None`` uses the algorithm's default.
    :param n_envs: env copies; the model sees ``n_envs * n_agents`` vector entries.
    :param seed: seeds the model and the env copies.
    :param hyperparams: the algorithm's keyword arguments (``n_steps`` counts steps per entry).
    :param deploy_temperature: how the trained team acts by default (see
        :attr:`~sb3_pm.agents.training.learned_team.LearnedTeam.deploy_temperature`).
    """

    name = "centralized"
    MANIFEST_FORMAT = MANIFEST_FORMAT
    OLD_FORMATS = OLD_FORMATS
    shares_one_network = True
    resizable = False
    accepts_deploy_filter = False  # its learn() trains through whatever filter it acts under
    omniscient = False  # it sees only what its agents observe, pooled

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
        tensorboard_log: str | Path | None = None,
        verbose: int = 0,
        device: str = "cpu",
        deploy_temperature: float | None = None,
        _init_model: bool = True,
    ) -> None:
        self._set_problem(
            graph,
            n_agents,
            n_envs,
            seed,
            algo,
            policy,
            {**dict(env_kwargs or {}), "shared_map": True},
            deploy_temperature,
        )
        if not isinstance(self.graph, GraphSpec):
            raise InputError(
                f"CentralizedPPO trains on one graph, not on the graph family {self.graph.name!r}"
            )
        self.hyperparams = dict(hyperparams or {})
        self.agents = [f"agent_{i}" for i in range(self.n_agents)]
        self.venv = make_parameter_sharing_vec_env(self.graph, self.n_envs, self.n_agents, self.env_kwargs)
        self.model: Any = None
        if _init_model:
            kwargs = resolve_hyperparams(self.hyperparams)
            self.model = self.algo_class(
                self.policy,
                self.venv,
                seed=self.seed,
                tensorboard_log=None if tensorboard_log is None else str(tensorboard_log),
                verbose=verbose,
                device=device,
                **kwargs,
            )
            try:
                check_advice_source({"shared policy": self.model}, self.env_kwargs)
                self._apply_deploy_temperature(self.deploy_temperature)
            except InputError:  # a prior without its column, or a sampling rule without the DCBF policy
                self.close()
                raise

    @classmethod
    def _config_options(cls, config: Any) -> dict[str, Any]:
        """The config entry's team arguments; per-agent overrides are refused (there is one network)."""
        if config.agents:
            raise InputError(f"{config.source}: per-agent overrides make no sense for a centralized team")
        if config.learning_rate_spread != 1.0:
            raise InputError(
                f"{config.source}: learning_rate_spread makes no sense for a centralized team (one "
                "network, one learning rate); set it to 1 (an experiment variant: hyperparams: "
                "{learning_rate_spread: 1}; sb3-pm train: --hyperparams learning_rate_spread:1)"
            )
        reward = config.env_kwargs.get("reward")
        if isinstance(reward, Mapping) and "territory" in reward:
            raise InputError(
                f"{config.source}: the territory reward makes no sense for a centralized team (one "
                "network acts for every agent and cannot tell whose territory a target is); give it "
                "a reward without the term (e.g. --env-kwargs 'reward:{clearing: 0.04, collision: 0.001}')"
            )
        if config.deploy_filter is not None:
            raise InputError(
                f"{config.source}: deploy_filter is not available for a centralized team (one network "
                "trains and acts through the same filter); set deploy_filter: null (an experiment "
                "variant: hyperparams: {deploy_filter: null}; sb3-pm train: --hyperparams deploy_filter:null)"
            )
        options = super()._config_options(config)
        options.pop("per_agent", None)
        options.pop("deploy_filter", None)
        return options

    @property
    def num_timesteps(self) -> int:
        """Agent-steps per agent taken so far (comparable with ``IndependentPPO.num_timesteps``)."""
        return int(self.model.num_timesteps) // self.n_agents

    def learn(
        self,
        total_timesteps: int,
        callback: Any = None,
        progress_bar: bool = False,
        reset_num_timesteps: bool = True,
    ) -> CentralizedPPO:
        """Train for ``total_timesteps`` steps per agent (``n_agents`` times that for the model)."""
        if total_timesteps < 1:
            raise InputError(f"total_timesteps must be positive, got {total_timesteps}")
        set_random_seed(learn_seed(self.seed, self.num_timesteps))
        self.model.learn(
            total_timesteps * self.n_agents,
            # Episode metrics in TensorBoard, as the decentralized learners log them (metrics/<name>).
            callback=with_episode_metrics(callback),
            progress_bar=progress_bar,
            reset_num_timesteps=reset_num_timesteps,
            tb_log_name="centralized",
        )
        return self

    def reset(self, env: Any, seed: int | None = None) -> None:
        """Start an episode; the env needs ``shared_map=True``, the setting the team was trained in."""
        super().reset(env, seed)
        if not getattr(getattr(env, "unwrapped", env), "shared_map", True):
            raise InputError("a centralized team needs an env with shared_map=True (its env_kwargs)")

    def policy_for(self, agent: str) -> Any:
        """The one shared policy: it acts for every agent, in one batch (:attr:`shares_one_network`)."""
        return self.model.policy

    def model_files(self) -> dict[str, Any]:
        """The one shared model."""
        return {MODEL_FILE: self.model}

    @classmethod
    def load(cls, path: str | Path, graph: GraphLike | None = None, device: str = "cpu") -> CentralizedPPO:
        """Load a team written by :meth:`save`; nothing stored in the folder runs (the model is
        built from the manifest, then given the zip's tensors and counters).

        :raises FileNotFoundError: for a missing folder, manifest or model.
        :raises OldTeamFormatError: for a team in the old format (``sb3-pm convert-team`` converts it).
        :raises InputError: if ``graph`` is not the graph the team was trained on.
        """
        folder, manifest, spec = cls.open_saved(path, graph, lambda manifest: [MODEL_FILE])
        team = cls(
            spec,
            n_agents=int(manifest["n_agents"]),
            env_kwargs=manifest["env_kwargs"],
            algo=manifest["algo"],
            policy=manifest["policy"],
            n_envs=int(manifest["n_envs"]),
            seed=int(manifest["seed"]),
            hyperparams=saved_hyperparams(folder / MANIFEST, manifest)[0],
            device=device,
            deploy_temperature=manifest.get("deploy_temperature"),
        )
        return team._restore_saved(folder, device, manifest)  # type: ignore[no-any-return]

    def close(self) -> None:
        """Close the env copies and the model's logger."""
        close_loggers([self.model] if self.model is not None else [])
        self.venv.close()
