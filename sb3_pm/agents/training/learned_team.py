""":class:`LearnedTeam`: what every trained team shares, whether its agents learn apart or together.

:class:`~sb3_pm.agents.training.team.IndependentPPO` (one learner per agent) and
:class:`~sb3_pm.sharing.centralized.CentralizedPPO` (one shared network) differ in how they train and
act. They share the rest: the problem they were built for (graph, team size, env settings,
algorithm, seed), the check that an episode runs on that graph, and saving to and loading from a
team folder (:mod:`sb3_pm.agents.deployment.saved_teams`).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.logger import Logger, configure
from stable_baselines3.common.utils import get_latest_run_id

from sb3_pm.agents.deployment.rule import DeploymentRule
from sb3_pm.agents.deployment.saved_teams import (
    MANIFEST,
    OldTeamFormatError,
    check_same_graph,
    graph_for_saved_team,
    old_format_message,
    read_manifest,
    save_graph_copy,
    save_model_atomic,
    team_manifest,
    write_manifest,
)
from sb3_pm.agents.training.learner_record import plain_hyperparams
from sb3_pm.agents.training.learners import resolve_learner
from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphFamily, GraphLike, GraphSpec, resolve_graph_or_family
from sb3_pm.policies.dcbf import FILTER_SWITCHES, SITE_BOUND


class LearnedTeam(DeploymentRule):
    """Base of the trained teams: the problem they were built for, the graph check, save and load.

    Subclasses set :attr:`MANIFEST_FORMAT` and :attr:`OLD_FORMATS`, call :meth:`_set_problem`
    first in ``__init__``, and provide :meth:`model_files` (which model goes in which zip).
    """

    #: The ``format`` field of this team kind's manifest.
    MANIFEST_FORMAT: ClassVar[str]
    #: Earlier formats of this kind, loadable only by unpickling: refused, convertible.
    OLD_FORMATS: ClassVar[tuple[str, ...]] = ()
    omniscient = False

    #: The graph the team was built for, or the family of graphs it trains on.
    graph: GraphSpec | GraphFamily
    n_agents: int
    n_envs: int
    seed: int
    algo_class: type[BaseAlgorithm]
    algo: str
    policy: str | type
    env_kwargs: dict[str, Any]
    #: see :attr:`deploy_filter`
    _deploy_filter: dict[str, Any] | None = None
    #: whether this kind of team can act under a deploy filter (each learner must train with the
    #: bound off and act with it on)
    accepts_deploy_filter: ClassVar[bool] = True

    def _set_problem(
        self,
        graph: GraphLike | GraphFamily,
        n_agents: int,
        n_envs: int,
        seed: int,
        algo: str | type | None,
        policy: str | type | None,
        env_kwargs: Mapping[str, Any] | None,
        deploy_temperature: float | None = None,
    ) -> None:
        """Resolve and check what the team is built for (raises :class:`InputError` naming a bad value).

        ``deploy_temperature`` is only checked and kept here; :meth:`_apply_deploy_temperature`
        hands it to the policies once they exist.
        """
        from sb3_pm.policies.sampling import check_deploy_temperature

        self._deploy_temperature = check_deploy_temperature(deploy_temperature)
        self.graph = resolve_graph_or_family(graph)
        if n_agents < 1:
            raise InputError(f"n_agents must be at least 1, got {n_agents}")
        if n_envs < 1:
            raise InputError(f"n_envs must be at least 1, got {n_envs}")
        self.n_agents, self.n_envs, self.seed = int(n_agents), int(n_envs), int(seed)
        self.algo_class, self.algo, self.policy, self.env_kwargs = resolve_learner(algo, policy, env_kwargs)
        for key in ("graph", "n_agents"):
            if key in self.env_kwargs:
                raise InputError(f"env_kwargs must not hold {key!r}: pass it to {type(self).__name__} itself")
        for key in ("failures", "failure_rate"):
            if self.env_kwargs.get(key):
                raise InputError(
                    f"env_kwargs {key!r}: agent failures are a deployment condition (evaluate's env_kwargs, "
                    "sb3-pm evaluate --fail); training runs every agent to the end of each episode"
                )

    @classmethod
    def from_config(cls, config: Any, graph: GraphLike | GraphFamily, seed: int = 0, **kwargs: Any) -> Any:
        """A team from a :class:`~sb3_pm.zoo.config.TrainConfig` (an entry of ``zoo/ippo.yml``).

        :param kwargs: further constructor arguments (``tensorboard_log``, ``verbose`` ...),
            overriding the config's.
        """
        options = {**cls._config_options(config), **kwargs}
        return cls(graph, seed=seed, **options)  # type: ignore[call-arg]  # subclasses take these

    @classmethod
    def _config_options(cls, config: Any) -> dict[str, Any]:
        """The constructor arguments a config entry sets."""
        return dict(config.team_kwargs())

    # ------------------------------------------------------------ acting
    def reset(self, env: Any, seed: int | None = None) -> None:
        """Start an episode on ``env``; checks it is the graph the team was built for.

        With a ``seed``, torch's global generator is seeded too, so stochastic
        (``deterministic=False``) actions are reproducible.
        """
        super().reset(env, seed)
        self._warn_if_site_bound_pending()
        self._episode_territories()
        other = getattr(getattr(env, "unwrapped", env), "graph", None)
        if isinstance(self.graph, GraphFamily) and isinstance(other, GraphSpec):
            raise InputError(
                f"the team was trained on the graph family {self.graph.name!r}; deploy it on graph "
                f"{other.name!r} with team.on_graph(graph) (observations of that graph's size)"
            )
        if isinstance(other, GraphSpec) and isinstance(self.graph, GraphSpec):
            check_same_graph(self.graph, other)
        if seed is not None:
            th.manual_seed(seed)

    # ------------------------------------------------- the deployment rule
    def acting_policies(self) -> dict[str, Any]:
        """``{model file: policy}``: every learner's policy (:class:`DeploymentRule`)."""
        return {name: model.policy for name, model in self.model_files().items()}

    # ------------------------------------------------------ the DCBF filter
    def _filter_territories(self) -> dict[str, tuple[int, ...]]:
        """``{model file: the target nodes of its agent's territory}`` on the team's graph
        (:meth:`~sb3_pm.agents.deployment.rule.DeploymentRule.set_filter`)."""
        from sb3_pm.graphs.territories import agent_territories

        files = list(self.model_files())
        if len(files) != self.n_agents:
            raise InputError(
                f"neglect_scope='territory' needs one learner per agent; this team has {len(files)} "
                f"model(s) for {self.n_agents} agents"
            )
        if not isinstance(self.graph, GraphSpec):
            raise InputError(
                "neglect_scope='territory' needs the team on one graph, not a graph family: "
                "deploy it with team.on_graph(graph) first"
            )
        return dict(zip(files, agent_territories(self.graph, self.n_agents)))

    @property
    def deploy_filter(self) -> dict[str, Any] | None:
        """The DCBF rules the trained team acts under beyond its training filter, or ``None``.

        The rules are ``{"neglect_bound": B, "neglect_scope": S}`` (rule 8; ``B`` ``None``: off),
        with ``"leave_cleared"`` / ``"pass_held"`` where rule 9 / rule 10 is switched
        (:mod:`sb3_pm.policies.dcbf`); with
        ``None`` the team acts under the filter it trained under.

        Set by the config's ``deploy_filter`` and saved with the team. Training never reads it:
        :meth:`learn` trains with the bound off and switches it on again when it returns, so the
        policies, the saved team and everything that evaluates it act under it.
        """
        return None if self._deploy_filter is None else dict(self._deploy_filter)

    @deploy_filter.setter
    def deploy_filter(self, deploy_filter: Mapping[str, Any] | None) -> None:
        previous, new = self._deploy_filter, self._checked_deploy_filter(deploy_filter)
        if previous is None and new is not None:
            self._check_training_bound()  # a bound trained in is not a deploy filter's to replace
        self._training_filter()  # the previous rule off (nothing to do without one)
        self._deploy_filter = new
        try:
            self._apply_deploy_filter()
        except InputError:  # e.g. learners without the DCBF filter: back to the previous rule
            self._training_filter()
            self._deploy_filter = previous
            self._apply_deploy_filter()
            raise

    def _checked_deploy_filter(self, deploy_filter: Mapping[str, Any] | None) -> dict[str, Any] | None:
        """``deploy_filter`` checked against this team; the models need not exist yet.

        :raises InputError: a malformed one, or scope ``territory`` where no territory can be given.
        """
        from sb3_pm.policies.dcbf import check_deploy_filter

        checked = check_deploy_filter(None if deploy_filter is None else dict(deploy_filter))
        if checked is not None and not self.accepts_deploy_filter:
            raise InputError(
                f"deploy_filter is not available for a {type(self).__name__} team (its one network "
                "trains and acts through the same filter); set it to null"
            )
        territorial = checked is not None and checked["neglect_scope"] == "territory"
        # auto is calibrated where the team is deployed, on that graph's territories, so a team
        # trained on a family takes it; a fixed territory bound needs the team's own graph.
        site_bound = checked is not None and checked["neglect_bound"] == SITE_BOUND
        if territorial and not site_bound and isinstance(self.graph, GraphFamily):
            raise InputError(
                "deploy_filter scope 'territory' needs one graph: a team trained on the graph family "
                f"{self.graph.name!r} has no territories"
            )
        return checked

    def _check_training_bound(self) -> None:
        """A deploy filter replaces the bound at deployment only, so training must have none.

        :raises InputError: a ``deploy_filter`` on learners that train with a neglect bound.
        """
        for name, model in self.model_files().items():
            if (model.policy_kwargs or {}).get("neglect_bound") is not None:
                raise InputError(
                    f"{name} trains with a neglect bound (policy_kwargs.neglect_bound) and the team has a "
                    "deploy_filter: keep one of them (the deploy filter switches its rules on after training "
                    "and off while training, the trained bound included)"
                )

    def _apply_deploy_filter(self) -> None:
        """Switch the :attr:`deploy_filter` on (nothing without one). ``auto`` has no number until
        a site is calibrated: the team waits for it (:attr:`site_bound_pending`) with no bound."""
        if self._deploy_filter is None:
            return
        if self._deploy_filter["neglect_bound"] == SITE_BOUND:
            rules = self._deploy_filter
            switches = {key: rules[key] for key in FILTER_SWITCHES if key in rules}
            if switches:  # kept when the bound is set (set_filter merges)
                self.set_filter(**switches)
            self.await_site_bound()
            return
        self.set_filter(**self._deploy_filter)

    def _training_filter(self) -> None:
        """Switch the :attr:`deploy_filter` off: every learner's bound as trained, that is none
        (a team with a deploy filter trains without a bound; nothing to do without one)."""
        from dataclasses import replace

        if self._deploy_filter is None:
            return
        self.site_bound_pending = False
        self.reset_filter()
        # A team saved before the manifest held filter_settings kept its bound in policy_kwargs, so
        # its policies were built with it: off for training here too.
        for policy in self.acting_policies().values():
            if getattr(policy, "use_dcbf", False) and policy.dcbf_config.neglect_bound is not None:
                policy.dcbf_config = replace(
                    policy.dcbf_config, neglect_bound=None, neglect_scope="known", territory=()
                )

    def _restore_acting_rule(self, manifest: Mapping[str, Any]) -> None:
        """A loaded team's acting rule from its manifest: the temperature, the filter settings it
        acted under when saved, then its ``deploy_filter`` (checked against the team)."""
        self._apply_deploy_temperature(self.deploy_temperature)
        settings = manifest.get("filter_settings") or {}
        if not isinstance(settings, Mapping):
            raise InputError(f"manifest filter_settings must be a mapping, got {settings!r}")
        if settings:
            self.set_filter(**settings)
        self._apply_deploy_filter()

    # ---------------------------------------------------------- SB3-style access
    #: the logger given to :meth:`set_logger`, if any
    _custom_logger: Logger | None = None

    def set_logger(self, logger: Logger) -> None:
        """Log the team's own scalars and evaluations (the team callbacks of
        :mod:`sb3_pm.agents.training.team_callbacks`) through ``logger``, an SB3 ``Logger``. Each
        learner keeps its own logger, as SB3 gives each model one."""
        self._custom_logger = logger

    def team_logger(self, tb_log_name: str | None = None) -> Logger:
        """The logger of the team's own scalars: :meth:`set_logger`'s, else a TensorBoard run
        ``<tb_log_name>team_<i>`` beside the agents' runs when the team has a ``tensorboard_log``,
        else one that writes nothing."""
        if self._custom_logger is not None:
            return self._custom_logger
        folder = getattr(self, "tensorboard_log", None)
        if folder is None:
            return Logger(folder=None, output_formats=[])
        name = f"{tb_log_name or ''}team"
        run = Path(folder) / f"{name}_{get_latest_run_id(str(folder), name) + 1}"
        return configure(str(run), ["tensorboard"])

    def get_parameters(self) -> dict[str, dict[str, dict[str, th.Tensor]]]:
        """``{model: its SB3 get_parameters()}``, one entry per model file (an agent's name for
        ``IndependentPPO``)."""
        return {
            name.removesuffix(".zip"): model.get_parameters() for name, model in self.model_files().items()
        }

    def set_parameters(
        self, parameters: Mapping[str, Mapping[str, Any]], exact_match: bool = True, device: str = "auto"
    ) -> None:
        """Load :meth:`get_parameters`'s output back, model by model (SB3's ``set_parameters``).

        :raises InputError: for a model this team does not have, or (``exact_match``) one missing.
        """
        models = {name.removesuffix(".zip"): model for name, model in self.model_files().items()}
        unknown = sorted(set(parameters) - set(models))
        missing = sorted(set(models) - set(parameters))
        if unknown or (exact_match and missing):
            raise InputError(f"set_parameters: unknown models {unknown}, missing models {missing}")
        for name, values in parameters.items():
            models[name].set_parameters(dict(values), exact_match=exact_match, device=device)

    # ---------------------------------------------------------- save / load
    def model_files(self) -> dict[str, BaseAlgorithm]:
        """``{file name: model}``: what :meth:`save` writes beside the manifest."""
        raise NotImplementedError

    @property
    def update_device(self) -> th.device | None:
        """Torch device of the learners' update phases (``train()``) when it is not their own
        ``device``, or ``None``: ``"cuda"`` with ``device="cpu"`` collects the rollouts on the CPU
        and updates on the GPU (:mod:`sb3_pm.ppo_dcbf.update_device`). Not saved with the team."""
        devices = {getattr(model, "update_device", None) for model in self.model_files().values()}
        return devices.pop() if len(devices) == 1 else None

    @update_device.setter
    def update_device(self, device: str | th.device | None) -> None:
        from sb3_pm.ppo_dcbf.update_device import check_update_device

        parsed = check_update_device(device)
        learners = self.model_files().values()
        others = sorted({type(model).__name__ for model in learners if not hasattr(model, "update_device")})
        if parsed is not None and others:
            raise InputError(f"update_device needs dcbf_ppo learners; this team has {', '.join(others)}")
        for model in learners:
            if hasattr(model, "update_device"):  # DCBFPPO learners
                model.update_device = parsed

    def manifest(self) -> dict[str, Any]:
        """What :meth:`save` writes to ``manifest.json``: the common fields and the hyperparameters
        in plain JSON (:mod:`.learner_record`), from which ``load`` rebuilds the learners.

        :raises InputError: for a hyperparameter with no plain form (a Python function as a schedule).
        """
        hyperparams = plain_hyperparams(getattr(self, "hyperparams", {}), "the team's hyperparams")
        return {**team_manifest(self, self.MANIFEST_FORMAT), "hyperparams": hyperparams}

    def save(self, path: str | Path, overwrite: bool = False) -> Path:
        """Save the team to the folder ``path`` (created if needed); the manifest is written last.

        :raises FileExistsError: if ``path`` already holds a team and ``overwrite`` is False.
        """
        folder = Path(path)
        if folder.exists() and not folder.is_dir():
            raise FileExistsError(f"{folder} exists and is not a folder")
        if folder.is_dir() and not overwrite and ((folder / MANIFEST).exists() or any(folder.glob("*.zip"))):
            raise FileExistsError(f"{folder} already holds a saved team; pass overwrite=True to replace it")
        manifest = self.manifest()  # first: a team whose settings have no plain form writes nothing
        folder.mkdir(parents=True, exist_ok=True)
        for name, model in self.model_files().items():
            save_model_atomic(model, folder / name)
        save_graph_copy(self.graph, folder)
        write_manifest(folder, manifest)  # last: a folder with a manifest holds a whole team
        return folder

    def close(self) -> None:
        """Release what the team holds (its env copies); subclasses that hold some override it."""

    def _restore_saved(self, folder: Path, device: str, manifest: Mapping[str, Any]) -> Any:
        """Load every model file's tensors and counters into the learners just built (nothing in
        the zips is unpickled: :func:`~sb3_pm.agents.deployment.model_files.restore_model`), then
        the acting rule; returns ``self``. On failure the team is closed (its env copies' workers
        stopped) before the error goes on."""
        from sb3_pm.agents.deployment.model_files import restore_model

        try:
            for name, model in self.model_files().items():
                restore_model(model, folder / name, device)
            self._restore_acting_rule(manifest)
        except BaseException:
            self.close()
            raise
        return self

    @classmethod
    def open_saved(
        cls, path: str | Path, graph: GraphLike | None, files: Any
    ) -> tuple[Path, dict[str, Any], GraphSpec | GraphFamily]:
        """The folder, manifest and graph of a saved team of this kind, every model file checked present.

        :param path: a saved team, or a run folder of ``sb3-pm train`` holding it in ``team/``.
        :param graph: the graph to run on (``None``: the saved one); it must be the trained problem.
        :param files: ``manifest -> [file names]``, the model files the team needs.
        :raises FileNotFoundError: if the folder, its manifest or a model file is missing.
        :raises OldTeamFormatError: if the team is in one of :attr:`OLD_FORMATS` (one line: how to
            convert it).
        :raises InputError: if the folder holds another kind of team, or ``graph`` is another problem.
        """
        folder = Path(path)
        if not (folder / MANIFEST).exists() and (folder / "team" / MANIFEST).exists():
            folder = folder / "team"  # a run folder written by ``sb3-pm train``
        if not folder.is_dir():
            raise FileNotFoundError(f"no saved team at {folder} (not a folder)")
        manifest = read_manifest(folder)
        kind = manifest.get("format")
        if kind in cls.OLD_FORMATS:
            raise OldTeamFormatError(old_format_message(folder, str(kind)))
        if kind != cls.MANIFEST_FORMAT:
            raise InputError(f"{folder} holds a {kind!r} team, not a {cls.MANIFEST_FORMAT!r} one")
        spec = graph_for_saved_team(folder, manifest, graph)
        missing = [str(folder / name) for name in files(manifest) if not (folder / name).exists()]
        if missing:
            raise FileNotFoundError(f"saved team {folder} is incomplete: missing {', '.join(missing)}")
        return folder, manifest, spec


__all__ = ["LearnedTeam"]
