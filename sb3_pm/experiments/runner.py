"""Run an experiment: train every learned (variant, graph, seed) cell that has not finished,
evaluate every cell, and write the paper-shaped tables, the ANOVA and the plots.

Layout of the output folder::

    DIR/
      experiment.yml            the experiment as run (after --quick and --graphs)
      command.txt
      cells/<variant>/<graph>/seed<k>/
          team/                 the trained team (learned variants); saved before evaluation, so a
                                sweep stopped during evaluation resumes without retraining
          tb/                   TensorBoard logs of its training
          evaluation.json       the cell's evaluation (EvaluationResult.to_dict())
      trained/<variant>/<train_env>/seed<k>/team/
                                the one team of a ``train_env`` variant and seed, trained before
                                the cells (one job each) and deployed zero-shot on every graph
          DONE                  written last, with the checksum of the cell's files: a cell with
                                a sound DONE is never run again, a damaged one runs again
      results.md results.csv results.tex anova.txt by_graph.md effects.md runs.md results.json
      marl_eval.json uncertainty.png table.png performance_profile.png training.png estimator_loss.png
      report.md                 all of the above on one page, with the code version and compute

A cell is one job; jobs run on a local process pool or on Ray (:mod:`.backends`). An interrupted
sweep resumes where it stopped: finished cells (those with ``DONE``) are read back, not re-run.
Every cell of every variant is evaluated on the same episodes (env seeds
``EVAL_SEED_OFFSET + seed * SEED_STRIDE + e``), so the comparison is paired.
"""

from __future__ import annotations

import json
import shlex
import shutil
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from sb3_pm.errors import InputError
from sb3_pm.evaluation import SEED_STRIDE, Comparison, EvaluationResult, evaluate
from sb3_pm.experiments.backends import WorkerLost, default_jobs, run_jobs
from sb3_pm.experiments.curves import plot_training_curves
from sb3_pm.experiments.integrity import DONE, reopen_damaged_cell, write_done
from sb3_pm.experiments.memory_needs import check_sweep_memory
from sb3_pm.experiments.preflight import check_update_device_takers
from sb3_pm.experiments.record import EVAL_SEED_OFFSET, experiment_record
from sb3_pm.experiments.report import code_version, write_report
from sb3_pm.experiments.spec import Experiment, Variant, variant_config
from sb3_pm.experiments.tracking import Tracking, check_wandb, wandb_run
from sb3_pm.files import move_aside, write_atomic
from sb3_pm.graphs import graph_label
from sb3_pm.machine import usable_cores, write_machine_record


@dataclass(frozen=True)
class Cell:
    """One (variant, graph, seed) job, in a form that pickles (for process pools and Ray)."""

    variant: dict[str, Any]
    graph: str
    seed: int
    folder: str
    config: str | None
    timesteps: int | None
    episodes: int
    max_cycles: int
    n_agents: int
    env_kwargs: dict[str, Any]
    hyperparams: dict[str, Any]
    #: The experiment's ``eval_env_kwargs``: added to the evaluation's env only.
    eval_env_kwargs: dict[str, Any] = field(default_factory=dict)
    #: torch device of a learned team; not part of the experiment record (results do not depend
    #: on where they ran, up to floating point).
    device: str = "cpu"
    #: torch device of a learned team's update phases alone (``IndependentPPO.update_device``;
    #: ``None``: ``device``); like ``device``, not part of the experiment record.
    update_device: str | None = None
    #: How many of a learned team's learners may update at once (``IndependentPPO.update_slots``;
    #: ``None``: one per core): the cores a job may use when jobs run side by side. Not part of the
    #: experiment record (the parameters are the same whatever the count).
    update_slots: int | None = None
    #: Where a ``train_env`` variant's team is trained (shared by its cells on every graph).
    team_folder: str | None = None
    #: The W&B run settings of the cell's training (``--track``), or ``None``: not tracked. Not
    #: part of the experiment record.
    tracking: Tracking | None = None

    @property
    def done(self) -> bool:
        return (Path(self.folder) / DONE).exists()


def cell_folder(out: Path, variant: Variant, graph: str, seed: int) -> Path:
    return out / "cells" / variant.key / graph_label(graph) / f"seed{seed}"


def training_folder(out: Path, variant: Variant, seed: int) -> Path:
    """Where a ``train_env`` variant trains its one team per seed."""
    assert variant.train_env is not None
    return out / "trained" / variant.key / graph_label(variant.train_env) / f"seed{seed}"


def plan_cells(
    experiment: Experiment,
    out: Path,
    device: str = "cpu",
    update_device: str | None = None,
    tracking: Tracking | None = None,
) -> list[Cell]:
    """Every cell of the grid, in table order."""
    cells = []
    for variant in experiment.variants:
        for graph in experiment.graphs:
            for seed in experiment.seeds:
                shared = None if variant.train_env is None else str(training_folder(out, variant, seed))
                cells.append(
                    Cell(
                        variant=asdict(variant),
                        graph=graph,
                        seed=seed,
                        folder=str(cell_folder(out, variant, graph, seed)),
                        config=None if experiment.config is None else str(experiment.config),
                        timesteps=experiment.timesteps,
                        episodes=experiment.episodes,
                        max_cycles=experiment.max_cycles,
                        n_agents=experiment.n_agents,
                        env_kwargs=dict(experiment.env_kwargs),
                        hyperparams=dict(experiment.hyperparams),
                        eval_env_kwargs=dict(experiment.eval_env_kwargs),
                        device=device,
                        update_device=update_device,
                        team_folder=shared,
                        tracking=tracking,
                    )
                )
    return cells


def _core_share(backend: str, n_jobs: int | None, trainings: int) -> int:
    """The update slots of each team when ``trainings`` teams train in jobs side by side."""
    if backend != "local":
        return 1  # a Ray task reserves one CPU
    return max(1, usable_cores() // max(1, min(n_jobs or default_jobs(), trainings)))


def _set_update_device(team: Any, cell: Cell) -> None:
    """Give ``team`` the cell's update device, closing the team if it refuses, and its update slots."""
    try:
        team.update_device = cell.update_device
    except InputError:
        team.close()
        raise
    if hasattr(team, "update_slots"):
        team.update_slots = cell.update_slots


def training_jobs(cells: list[Cell]) -> list[Cell]:
    """One cell per ``train_env`` variant and seed whose shared team is not saved, or does not load
    (kept aside, like a damaged cell's team): the job that trains it, with the first such cell's
    other fields."""
    jobs: dict[str, Cell] = {}
    for cell in cells:
        if cell.team_folder is None or cell.team_folder in jobs:
            continue
        team = _load_finished_team(Path(cell.team_folder) / "team", cell.device)
        if team is None:
            jobs[cell.team_folder] = cell
        else:
            team.close()
    return list(jobs.values())


def train_shared_team(cell: Cell) -> str:
    """Train (or resume) and save the shared team of a ``train_env`` cell; returns its folder."""
    import torch

    torch.set_num_threads(1)
    assert cell.team_folder is not None
    folder = Path(cell.team_folder)
    folder.mkdir(parents=True, exist_ok=True)
    _train(cell, Variant(**cell.variant), folder)
    return str(folder)


def cell_config(cell: Cell, variant: Variant) -> Any:
    """The training config of a learned cell: the base config's entry for the cell's graph, with the
    experiment's and then the variant's settings merged over it and checked as the file's own keys
    (:func:`~sb3_pm.experiments.spec.variant_overrides`)."""
    return variant_config(
        variant, cell.config, cell.graph, cell.hyperparams, cell.env_kwargs, cell.max_cycles, cell.n_agents
    )


def _train(cell: Cell, variant: Variant, folder: Path) -> Any:
    """Train the learned team of a cell and save it to ``folder/team``; with the cell's
    :attr:`~Cell.tracking`, its training is one W&B run named after the cell's folder."""
    config = cell_config(cell, variant)
    timesteps = variant.timesteps or cell.timesteps or config.n_timesteps
    from sb3_pm.agents.training.checkpoints import CHECKPOINTS
    from sb3_pm.agents.training.team import IndependentPPO
    from sb3_pm.sharing.centralized import CentralizedPPO

    team_class: Any = CentralizedPPO if variant.kind == "centralized" else IndependentPPO
    graph = variant.train_env or cell.graph
    record = {**config.to_dict(), "n_timesteps": timesteps, "variant": variant.key, "env": str(graph)}
    record["seed"] = cell.seed
    with wandb_run(cell.tracking if variant.train else None, folder, "/".join(folder.parts[-3:]), record):
        if variant.train and team_class is IndependentPPO:
            team = _train_with_checkpoints(cell, config, timesteps, folder, graph)
        else:
            team = team_class.from_config(
                config, graph, seed=cell.seed, tensorboard_log=str(folder / "tb"), device=cell.device
            )
            if variant.train:
                _set_update_device(team, cell)
                team.learn(timesteps)
    team.save(folder / "team", overwrite=True)
    # The machine that trained the team: the same seed trains another team on another kind of CPU.
    write_machine_record(folder)
    shutil.rmtree(folder / CHECKPOINTS, ignore_errors=True)  # the saved team supersedes them
    return team


#: Rollouts between two checkpoints of a training cell (a 50,000-step cell has 100 rollouts).
CELL_CHECKPOINT_EVERY = 10
#: ... or seconds, whichever comes first: ten rollouts of 16 learners on 200 nodes take over an hour
#: on two cores, which a cut session would lose.
CELL_CHECKPOINT_SECONDS = 900.0


def _train_with_checkpoints(cell: Cell, config: Any, timesteps: int, folder: Path, graph: str) -> Any:
    """Train a decentralized cell with checkpoints in ``folder/checkpoints``, continuing from the
    newest one a stopped sweep left there (bit for bit, so a resumed sweep loses no training)."""
    from sb3_pm.agents.training.checkpoints import CHECKPOINTS, CheckpointError, CheckpointSchedule
    from sb3_pm.agents.training.team import IndependentPPO

    schedule = CheckpointSchedule(
        folder / CHECKPOINTS, every=CELL_CHECKPOINT_EVERY, every_seconds=CELL_CHECKPOINT_SECONDS
    )
    tensorboard_log = str(folder / "tb")
    if (folder / CHECKPOINTS).is_dir():
        try:
            team = IndependentPPO.from_checkpoint(folder, device=cell.device, tensorboard_log=tensorboard_log)
        except CheckpointError as error:
            aside = move_aside(folder / CHECKPOINTS)
            print(f"warning: {error}; kept as {aside}, training the cell from the start", file=sys.stderr)
        else:
            if team.seed == cell.seed and team.num_timesteps + team.remaining_timesteps == timesteps:
                _set_update_device(team, cell)
                return team.learn_remaining(schedule)
            team.close()
            aside = move_aside(folder / CHECKPOINTS)
            print(f"warning: the checkpoints of {folder} are another run's; kept as {aside}", file=sys.stderr)
    team = IndependentPPO.from_config(
        config, graph, seed=cell.seed, tensorboard_log=tensorboard_log, device=cell.device
    )
    _set_update_device(team, cell)
    team.learn(timesteps, checkpoints=schedule)
    return team


def _load_finished_team(folder: Path, device: str = "cpu") -> Any:
    """A team this cell already trained and saved (the sweep stopped during its evaluation), or None."""
    if not (folder / "manifest.json").exists():
        return None
    from sb3_pm.evaluation.teams import load_trained_team

    try:
        return load_trained_team(folder, device=device)
    except (ValueError, FileNotFoundError) as error:  # damaged: keep it aside, train again
        aside = move_aside(folder)
        print(f"warning: {error}; kept as {aside}, training the cell again", file=sys.stderr)
        return None


def schedule(cells: list[Cell]) -> list[Cell]:
    """The cells in the order to submit them: the longest first.

    A pool that starts the short baseline cells and the small graphs first ends with one worker
    training a 200-node team while the others sit idle; longest-first keeps every worker busy until
    the end. Cost is estimated as (learned, node count); results do not depend on the order.
    """
    from sb3_pm.graphs import resolve_graph

    sizes = {graph: resolve_graph(graph).n_nodes for graph in {cell.graph for cell in cells}}

    def cost(cell: Cell) -> tuple[bool, int]:
        return Variant(**cell.variant).learned and cell.team_folder is None, sizes[cell.graph]

    return sorted(cells, key=cost, reverse=True)  # stable: table order within equal costs


def run_cell(cell: Cell) -> dict[str, Any]:
    """Train (if learned) and evaluate one cell; write ``evaluation.json`` and then ``DONE``."""
    import torch

    from sb3_pm.agents.training.learned_team import LearnedTeam

    torch.set_num_threads(1)  # one job per core: threads inside a job would oversubscribe
    folder = Path(cell.folder)
    if cell.done:
        return json.loads((folder / "evaluation.json").read_text())
    folder.mkdir(parents=True, exist_ok=True)
    variant = Variant(**cell.variant)
    started = time.time()
    if cell.team_folder is not None:  # trained once on train_env, deployed here zero-shot
        from sb3_pm.evaluation.teams import load_trained_team

        team = load_trained_team(Path(cell.team_folder) / "team", graph=cell.graph, device=cell.device)
        env_kwargs: dict[str, Any] = {}  # the team's own settings: evaluate() applies them
    elif variant.learned:
        team = _load_finished_team(folder / "team", cell.device) or _train(cell, variant, folder)
        env_kwargs = {}
    else:
        from sb3_pm.baselines import make_team

        assert variant.policy is not None
        team = make_team(variant.policy)
        # A baseline variant's env_kwargs set its environment (a baseline under a learned
        # variant's setting, e.g. target_knowledge: known), over the experiment's.
        env_kwargs = {**cell.env_kwargs, **variant.env_kwargs}
    env_kwargs.update(cell.eval_env_kwargs)
    if variant.learned:
        # The experiment file's rule (config, then the variant's pin), also for a team trained by
        # an earlier run or copied in, whose manifest may hold another.
        config = cell_config(cell, variant)
        team.deploy_temperature = config.deploy_temperature
        if isinstance(team, LearnedTeam):  # a transferred team keeps its source's
            team.deploy_filter = config.deploy_filter
    result = evaluate(
        team,
        cell.graph,
        n_agents=cell.n_agents,
        episodes=cell.episodes,
        seed=EVAL_SEED_OFFSET + cell.seed * SEED_STRIDE,
        max_cycles=cell.max_cycles,
        env_kwargs=env_kwargs,
        policy_name=variant.label,
    )
    payload = result.to_dict(traces=True)
    payload["cell"] = {
        "variant": variant.key,
        "graph": cell.graph,
        "seed": cell.seed,
        "seconds": time.time() - started,
        "code": code_version(),
    }
    write_atomic(folder / "evaluation.json", json.dumps(payload, indent=2))
    write_done(folder)
    return payload


def reproduce(
    experiment: Experiment,
    out: str | Path,
    backend: str = "local",
    n_jobs: int | None = None,
    ray_address: str | None = None,
    progress: bool = True,
    command: list[str] | None = None,
    device: str = "cpu",
    update_device: str | None = None,
    tracking: Tracking | None = None,
) -> Comparison:
    """Run (or resume) ``experiment`` into ``out`` and write its reports; returns the comparison.

    :param device: torch device of the learned teams (``cpu``, ``cuda``, ``auto``).
    :param update_device: torch device of the learned teams' update phases alone (e.g. ``cuda``
        with ``device="cpu"``: :attr:`~sb3_pm.agents.training.team.IndependentPPO.update_device`).
    :param tracking: track each cell's training as one W&B run
        (:mod:`sb3_pm.experiments.tracking`), grouped under the experiment's name unless it names a
        group; ``None``: no tracking.
    """
    out = Path(out)
    if tracking is not None:  # before anything is written
        check_wandb("tracking")
        tracking = tracking if tracking.group is not None else replace(tracking, group=experiment.name)
    cells = plan_cells(experiment, out, device=device, update_device=update_device, tracking=tracking)
    if update_device is not None:  # before the folder is written and hours of training start
        check_update_device_takers(update_device, cells)
    # every cell's memory, from sizes, before the folder is written and any env allocated
    check_sweep_memory(
        [cell for cell in cells if not cell.done], backend, n_jobs or default_jobs(), experiment.name
    )
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / "experiment.yml", yaml.safe_dump(experiment_record(experiment), sort_keys=False))
    write_atomic(out / "command.txt", shlex.join(command or sys.argv) + "\n")
    for cell in cells:
        damage = reopen_damaged_cell(Path(cell.folder)) if cell.done else None
        if damage is not None:
            print(f"warning: finished cell is damaged, running it again: {damage}", file=sys.stderr)
    todo = schedule([cell for cell in cells if not cell.done])
    jobs = training_jobs(todo)
    # Jobs side by side share the cores: each team's updates get its share of them as update slots
    # (a Ray task reserves one CPU). Shared teams train in a phase of their own, before the cells.
    jobs = [replace(cell, update_slots=_core_share(backend, n_jobs, len(jobs))) for cell in jobs]
    training = sum(1 for cell in todo if Variant(**cell.variant).learned and cell.team_folder is None)
    todo = [replace(cell, update_slots=_core_share(backend, n_jobs, training)) for cell in todo]
    if jobs:  # the shared teams first: the cells that deploy them wait for them
        print(f"{experiment.name}: training {len(jobs)} shared team(s) (train_env variants) before the cells")
        run_jobs(train_shared_team, jobs, backend=backend, n_jobs=n_jobs, ray_address=ray_address)
    bar = None
    if progress and todo:
        from sb3_pm.progress import progress_bar

        bar = progress_bar(
            len(todo), f"{experiment.name} ({len(cells) - len(todo)} of {len(cells)} cells were done)", "cell"
        )
    try:
        run_jobs(
            run_cell,
            todo,
            backend=backend,
            n_jobs=n_jobs,
            ray_address=ray_address,
            on_done=(lambda index, result: bar.update(1)) if bar is not None else None,
            label=lambda cell: str(Path(cell.folder).relative_to(out)),
        )
    except WorkerLost as error:  # the cells that finished are kept: the same command resumes the rest
        raise WorkerLost(
            f"{experiment.name}: {error}; run the same command again to resume", error.lost
        ) from None
    finally:
        if bar is not None:
            bar.close()
    comparison = Comparison(config=experiment_record(experiment))
    for cell in cells:
        payload = json.loads((Path(cell.folder) / "evaluation.json").read_text())
        comparison.results.setdefault(cell.variant["label"], []).append(EvaluationResult.from_dict(payload))
    comparison.write(out)
    for name in ("table.md", "table.csv", "table.tex"):  # the names for the paper's table
        (out / name).replace(out / name.replace("table", "results"))
    plot_training_curves(cells, out)
    write_report(out, experiment_record(experiment), cells, reference=comparison.reference_policy or "")
    return comparison


__all__ = [
    "EVAL_SEED_OFFSET",
    "Cell",
    "cell_config",
    "experiment_record",
    "plan_cells",
    "reproduce",
    "run_cell",
]
