"""Running a team for a number of episodes and keeping the per-episode records.

Seeding (reproducible, documented in the README): episode ``e`` of ``evaluate(..., seed=s)``
resets the environment with seed ``s + e`` (start positions and, if enabled, initial
uncertainties) and the team with :func:`team_seed` of that env seed, so a team's randomness never
shares a stream with the environment's.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sb3_pm.errors import InputError
from sb3_pm.evaluation.optimality import add_gap, episode_bound
from sb3_pm.evaluation.settling import Settling, SettlingRecorder
from sb3_pm.graphs import GraphLike, graph_label, resolve_graph
from sb3_pm.team_interface import Team

#: Mixed into the team's seed so that it differs from the env's seed for the same episode.
_TEAM_SEED_TAG = 0x7EA


def team_seed(env_seed: int) -> int:
    """The team's seed for an episode whose env seed is ``env_seed``."""
    return int(np.random.SeedSequence([int(env_seed), _TEAM_SEED_TAG]).generate_state(1)[0])


@dataclass
class EpisodeRecord:
    """One evaluated episode.

    :ivar episode: index within its :func:`evaluate` call.
    :ivar seed: the env's reset seed.
    :ivar team_seed: the team's reset seed.
    :ivar metrics: the env's metrics dict (``avg_uncertainty``, ``max_neglect``, ...).
    :ivar trace: ``(K,)`` summed target uncertainty after each step.
    :ivar settling: where each agent settled (:mod:`sb3_pm.evaluation.settling`), if recorded.
    """

    episode: int
    seed: int
    team_seed: int
    metrics: dict[str, float]
    trace: np.ndarray = field(repr=False)
    settling: Settling | None = field(default=None, repr=False)

    def to_dict(self) -> dict[str, float | int]:
        """A flat JSON-ready dict: the metrics plus ``episode``, ``seed`` and ``team_seed``."""
        return {"episode": self.episode, "seed": self.seed, "team_seed": self.team_seed, **self.metrics}


@dataclass
class EvaluationResult:
    """The episodes of one team on one graph, with their aggregates.

    :ivar policy: the team's name.
    :ivar graph: the graph's label (preset name or file stem).
    :ivar config: how the run was made (agents, steps, episodes, seed, env kwargs).
    :ivar episodes_requested: for an evaluation stopped before its end (Ctrl-C, SIGTERM:
        :class:`EvaluationInterrupted`), the number of episodes it was asked for; ``None`` for a
        complete one. ``episodes`` then holds the finished episodes only.
    """

    policy: str
    graph: str
    config: dict[str, Any]
    episodes: list[EpisodeRecord]
    episodes_requested: int | None = None

    @property
    def partial(self) -> bool:
        """Whether this evaluation was stopped before all its episodes finished."""
        return self.episodes_requested is not None and len(self.episodes) < self.episodes_requested

    @property
    def metric_names(self) -> list[str]:
        """Metric keys, in the env's order."""
        if not self.episodes:
            return []
        return list(self.episodes[0].metrics)

    def values(self, metric: str) -> np.ndarray:
        """``(episodes,)`` values of one metric."""
        return np.array([record.metrics[metric] for record in self.episodes], dtype=float)

    @property
    def mean(self) -> dict[str, float]:
        """Mean of each metric over the episodes that define it (NaN values, such as the uncertainty
        after a failure in an episode where no agent failed, are left out; NaN if none define it)."""
        return {name: _defined_mean(self.values(name)) for name in self.metric_names}

    @property
    def std(self) -> dict[str, float]:
        """Sample standard deviation (``ddof=1``; 0 for a single episode) of each metric."""
        return {name: _sample_sd(self.values(name)) for name in self.metric_names}

    @property
    def traces(self) -> np.ndarray:
        """``(episodes, K)`` summed target uncertainty per step."""
        return np.stack([record.trace for record in self.episodes])

    def to_dict(self, traces: bool = False) -> dict[str, Any]:
        """``{"episodes": [...], "mean": {...}, "std": {...}, "config": {...}}`` (the ``--json`` schema).

        A :attr:`partial` result also says ``"partial": true``, ``"episodes_finished"`` and
        ``"episodes_requested"`` (``config["episodes"]`` stays the number asked for).

        :param traces: also store each episode's uncertainty trace (``"traces"``), so that
            :meth:`from_dict` restores the result completely.
        """
        payload: dict[str, Any] = {
            "episodes": [record.to_dict() for record in self.episodes],
            "mean": self.mean,
            "std": self.std,
            "config": dict(self.config),
        }
        if self.partial:
            payload.update(
                partial=True, episodes_finished=len(self.episodes), episodes_requested=self.episodes_requested
            )
        if traces:
            payload["traces"] = [record.trace.tolist() for record in self.episodes]
        if any(record.settling is not None for record in self.episodes):
            payload["settling"] = [
                None if record.settling is None else record.settling.to_dict() for record in self.episodes
            ]
        return payload

    @classmethod
    def from_dict(cls, payload: dict[str, Any]) -> EvaluationResult:
        """The inverse of ``to_dict(traces=True)`` (traces are empty if they were not stored)."""
        traces = payload.get("traces") or [[] for _ in payload["episodes"]]
        settlings = payload.get("settling") or [None for _ in payload["episodes"]]
        records = []
        for row, trace, settled in zip(payload["episodes"], traces, settlings, strict=True):
            metrics = {k: v for k, v in row.items() if k not in ("episode", "seed", "team_seed")}
            episode, seed, seed_of_team = int(row["episode"]), int(row["seed"]), int(row["team_seed"])
            trace_array = np.asarray(trace, dtype=float)
            record = EpisodeRecord(episode, seed, seed_of_team, metrics, trace_array)
            record.settling = None if settled is None else Settling.from_dict(settled)
            records.append(record)
        config = payload["config"]
        requested = payload.get("episodes_requested") if payload.get("partial") else None
        return cls(
            policy=config["policy"],
            graph=config["graph"],
            config=config,
            episodes=records,
            episodes_requested=None if requested is None else int(requested),
        )


class EvaluationInterrupted(KeyboardInterrupt):
    """:func:`evaluate` stopped by Ctrl-C (or a ``KeyboardInterrupt`` raised for SIGTERM): the
    episodes it finished, as a :attr:`~EvaluationResult.partial` ``result``.

    A ``KeyboardInterrupt`` still, so code that stops on Ctrl-C stops here too; code that keeps
    what was finished (``sb3-pm evaluate --json``) catches this one. ``exit_status`` is the
    interrupt's own (130 for Ctrl-C unless the interrupt carried another, e.g. 143 for SIGTERM).
    """

    def __init__(self, result: EvaluationResult, exit_status: int = 130) -> None:
        finished = len(result.episodes)
        super().__init__(f"interrupted after {finished} of {result.episodes_requested} episodes")
        self.result = result
        self.exit_status = int(exit_status)

    def __reduce__(self) -> tuple[Any, ...]:
        # as its arguments, not its message: a sweep's worker process sends it to the parent pickled
        return type(self), (self.result, self.exit_status)


def _defined_mean(values: np.ndarray) -> float:
    defined = values[~np.isnan(values)]
    return float(defined.mean()) if len(defined) else float("nan")


def _sample_sd(values: np.ndarray) -> float:
    values = values[~np.isnan(values)]
    return float(values.std(ddof=1)) if len(values) > 1 else 0.0


def evaluate(
    team: Team,
    graph: GraphLike | None = None,
    n_agents: int | None = None,
    episodes: int = 10,
    seed: int = 0,
    max_cycles: int = 500,
    env_kwargs: Mapping[str, Any] | None = None,
    progress: bool | None = False,
    policy_name: str | None = None,
    deterministic: bool | None = None,
    threads: int | None = 1,
    settle_since: int | None = None,
) -> EvaluationResult:
    """Run ``team`` for ``episodes`` full episodes on ``graph`` and collect their metrics.

    :param team: any :class:`~sb3_pm.team_interface.Team` (a baseline or a trained team). A trained
        team whose ``deploy_filter`` is ``{neglect_bound: auto}`` and has no bound for this graph
        yet (``site_bound_pending``) gets one first, calibrated here with these ``n_agents``,
        ``env_kwargs`` and ``max_cycles`` (:func:`~sb3_pm.evaluation.neglect_calibration.settle_site_bound`;
        recorded in ``config["neglect_calibration"]``), and keeps it.
    :param graph: a preset name, a ``.graphml`` path or a :class:`~sb3_pm.graphs.GraphSpec`;
        ``None``: the trained team's own graph.
    :param n_agents: team size; ``None``: the trained team's own size, else 4.
    :param episodes: number of episodes, at least 1.
    :param seed: episode ``e`` uses env seed ``seed + e`` (see the module docstring).
    :param max_cycles: episode length K.
    :param env_kwargs: further arguments of the environment (``obs_radius``, ``failure_rate``,
        ...), over the team's own settings (:meth:`~sb3_pm.team_interface.Team.env_settings`: a
        trained team acts in the env it was trained in, whichever route evaluates it).
    :param progress: report progress on stderr (:func:`sb3_pm.progress.progress_bar`: a tqdm bar on
        a terminal, a plain line every 30 s elsewhere); ``False`` (default) is silent.
    :param policy_name: the label in reports; defaults to ``team.name``.
    :param deterministic: passed to ``team.predict_dict``; ``False`` samples a learned team's actions
        (from the team's own seeded stream, so still reproducible) at the team's sampling
        temperature: its ``deploy_temperature`` if it has one, else 1 unless
        ``set_sampling_temperature`` said otherwise. ``None`` (default) follows the team's
        ``deploy_temperature``: deterministic unless its config set a sampling temperature
        (``Team.acts_deterministically``). Baselines ignore it. A sampled run records the
        temperature in ``config["temperature"]``.
    :param threads: torch CPU threads while the episodes run, restored afterwards (default 1;
        ``None`` leaves torch's setting alone). A learned team's per-step forward passes are far
        too small to gain from intra-op threads: one episode took 31 s of wall time with one
        thread and 60 s with torch's default two on the 2-core development machine.
    :param settle_since: record where each agent settles after the episode's first
        ``settle_since`` steps (each record's ``settling``; :mod:`sb3_pm.evaluation.settling`);
        ``None`` (default) records nothing.
    :raises ValueError: for ``episodes < 1``, ``threads < 1`` or bad environment arguments.
    :raises EvaluationInterrupted: on Ctrl-C (a ``KeyboardInterrupt``) during the episodes, with the
        episodes that finished before it as a partial result.
    """

    if episodes < 1:
        raise InputError(f"episodes must be at least 1, got {episodes}")
    if threads is not None and threads < 1:
        raise InputError(f"threads must be at least 1, got {threads}")
    if settle_since is not None and not 0 <= settle_since < max_cycles:
        raise InputError(
            f"settle_since must be in [0, {max_cycles}) for {max_cycles}-step episodes, got {settle_since}"
        )
    graph = team.default_graph() if graph is None else graph
    if graph is None:
        raise InputError(f"evaluate needs a graph for {team.name!r}")
    spec = resolve_graph(graph)
    n_agents = (team.n_agents or 4) if n_agents is None else int(n_agents)
    deterministic = team.acts_deterministically(deterministic)
    kwargs = {**team.env_settings(), **dict(env_kwargs or {})}
    calibration = None
    if team.site_bound_pending:  # deploy_filter auto, no bound for this site yet
        from sb3_pm.evaluation.neglect_calibration import settle_site_bound

        calibration = settle_site_bound(team, spec, n_agents, kwargs, max_cycles)
    env = team.make_env(spec, n_agents=n_agents, max_cycles=max_cycles, **kwargs)
    run = {
        "n_agents": n_agents,
        "max_cycles": max_cycles,
        "episodes": episodes,
        "seed": seed,
        "env_kwargs": kwargs,
        "deterministic": deterministic,
    }
    records: list[EpisodeRecord] = []
    bar = _progress_bar(
        episodes * max_cycles, progress, f"{policy_name or team.name} on {graph_label(graph)}"
    )
    try:
        with torch_threads(threads):
            for episode in range(episodes):
                env_seed = seed + episode
                recorder = None if settle_since is None else SettlingRecorder(settle_since)
                records.append(
                    run_episode(team, env, env_seed, bar, deterministic=deterministic, recorder=recorder)
                )
                records[-1].episode = episode
    except KeyboardInterrupt as interrupt:
        # The episodes that finished are whole results: kept, marked partial, for the caller to save.
        partial = _result(team, graph, policy_name, run, records, calibration, requested=episodes)
        raise EvaluationInterrupted(partial, getattr(interrupt, "exit_status", 130)) from interrupt
    except BaseException:
        if calibration is not None:  # e.g. a graph the team refuses: the bound is not its site's
            from sb3_pm.evaluation.neglect_calibration import unsettle_site_bound

            unsettle_site_bound(team)
        raise
    finally:
        if bar is not None:
            bar.close()
        env.close()
    return _result(team, graph, policy_name, run, records, calibration)


def _result(
    team: Team,
    graph: GraphLike,
    policy_name: str | None,
    run: dict[str, Any],
    records: list[EpisodeRecord],
    calibration: Any,
    requested: int | None = None,
) -> EvaluationResult:
    """The :class:`EvaluationResult` of ``records``, its config saying how the run was made
    (``run``: sizes, seed, env settings, acting rule); ``requested``: see ``episodes_requested``."""
    label, graph_name = policy_name or team.name, graph_label(graph)
    config: dict[str, Any] = {"policy": label, "graph": graph_name, **run}
    # what a learned team sampled at, and the neglect bound it acted under (rule 8)
    config.update(team.acting_record(run["deterministic"]))
    if calibration is not None:  # how its deploy_filter auto found that bound (or none) here
        config["neglect_calibration"] = calibration.to_dict()
    return EvaluationResult(label, graph_name, config, records, episodes_requested=requested)


@contextmanager
def torch_threads(threads: int | None) -> Iterator[None]:
    """Run the block with ``threads`` torch CPU threads, then restore the previous count.

    Does nothing for ``None``, or when torch has not been imported (a baseline team never needs
    it, and importing it here would cost seconds).
    """
    torch = sys.modules.get("torch")
    if threads is None or torch is None:
        yield
        return
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def run_episode(
    team: Team,
    env: Any,
    env_seed: int,
    bar: Any = None,
    frames: Any = None,
    deterministic: bool = True,
    recorder: SettlingRecorder | None = None,
) -> EpisodeRecord:
    """Play one episode of ``env`` with ``team``; hand each rendered frame to ``frames.append`` if
    given (a list, or a writer that streams them to disk: :class:`~sb3_pm.evaluation.gif.GifWriter`),
    and let ``recorder`` see the env after every step (the record's ``settling`` is its result)."""
    observations, _ = env.reset(seed=env_seed)
    bound = episode_bound(env.unwrapped)
    t_seed = team_seed(env_seed)
    team.reset(env, seed=t_seed)
    if frames is not None:
        frames.append(env.render())
    infos: dict[str, dict] = {}
    steps = 0
    while env.agents:
        actions = team.predict_dict(observations, deterministic=deterministic)
        observations, _, _, _, infos = env.step(actions)
        if len(observations) > len(env.agents):  # agents that failed this step leave the team
            observations = {agent: obs for agent, obs in observations.items() if agent in env.agents}
        steps += 1
        if recorder is not None:
            recorder(env.unwrapped)
        if frames is not None:
            frames.append(env.render())
        if bar is not None and steps % 50 == 0:
            bar.update(50)
    if bar is not None:
        bar.update(steps % 50)
    metrics = next(iter(infos.values()))["metrics"] if infos else env.unwrapped.episode_metrics()
    return EpisodeRecord(
        episode=0,
        seed=int(env_seed),
        team_seed=t_seed,
        metrics=add_gap(metrics, bound),
        trace=env.unwrapped.uncertainty_trace(),
        settling=None if recorder is None else recorder.result(),
    )


def _progress_bar(total: int, progress: bool | None, description: str) -> Any:
    from sb3_pm.progress import progress_bar

    return progress_bar(total, description, unit="step", enabled=progress)
