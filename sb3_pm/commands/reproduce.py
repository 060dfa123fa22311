"""``sb3-pm reproduce``: run an experiment file (the paper's tables, or any other) end to end, resumably."""

from __future__ import annotations

import argparse
import signal
from dataclasses import replace
from pathlib import Path
from typing import Any

from sb3_pm.commands.tracking import add_tracking_options, check_tracking, tracking_of


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "reproduce",
        help="train and evaluate an experiment grid (zoo/experiments/*.yml), resumably",
        description=(
            "Train every (variant, graph, seed) cell that has no finished run in --out, evaluate every "
            "cell on the same episodes, and write results.md/.csv/.tex, by_graph.md, effects.md, anova.txt, "
            "results.json, the plots and report.md (all of them on one page). Rerunning the same command "
            "resumes an interrupted sweep."
        ),
    )
    parser.add_argument(
        "experiment",
        help="an experiment YAML: a path, or the name of a shipped one (comparison, ablation, ...; "
        "the repository's zoo/experiments/)",
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory (reused to resume)")
    parser.add_argument(
        "--quick", action="store_true", help="tiny budgets for a smoke test; its numbers are not results"
    )
    parser.add_argument(
        "--graphs", nargs="+", help="override the experiment's graphs (presets or .graphml paths)"
    )
    parser.add_argument("--seeds", nargs="+", type=int, help="override the experiment's training seeds")
    parser.add_argument("--timesteps", type=int, help="override the training budget (steps per learner)")
    parser.add_argument(
        "--variants",
        nargs="+",
        metavar="KEY",
        help="run only these variants (keys of the file's 'variants', in the file's order; the first "
        "one kept is the reference of effects.md)",
    )
    parser.add_argument(
        "--backend", choices=["local", "ray"], default="local", help="where cells run (default local)"
    )
    parser.add_argument(
        "--ray-address", help="address of an existing Ray cluster (default: start a local one)"
    )
    parser.add_argument("--jobs", type=int, help="parallel cells (default: one per core)")
    parser.add_argument("--no-progress", action="store_true", help="never show progress")
    parser.add_argument(
        "--device", default="cpu", help="torch device of the learned teams: cpu, cuda, auto (default cpu)"
    )
    parser.add_argument(
        "--update-device",
        default=None,
        metavar="DEVICE",
        help="torch device of the learned teams' update phases alone, e.g. cuda with --device cpu: "
        "rollouts on the CPU, updates on the GPU (default: --device)",
    )
    add_tracking_options(parser, "each training cell's TensorBoard logs (one W&B run per cell)")
    parser.set_defaults(func=run)


#: Seconds to wait for a Ray cluster's address to accept a connection.
RAY_CONNECT_SECONDS = 10.0


def check_ray(address: str | None) -> None:
    """Before anything is written: Ray is installed, and a cluster address answers.

    ``ray.init`` on an unreachable address retried for minutes without a word; a plain TCP
    connection with a timeout says the same in seconds.
    """
    import importlib.util
    import socket

    from sb3_pm.errors import UsageError

    if importlib.util.find_spec("ray") is None:
        raise UsageError("--backend ray needs Ray: pip install -e '.[ray]' (or pip install ray)")
    if not address or address == "auto":
        return
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise UsageError(f"--ray-address {address!r}: expected HOST:PORT")
    try:
        socket.create_connection((host, int(port)), timeout=RAY_CONNECT_SECONDS).close()
    except OSError as error:
        raise UsageError(
            f"--ray-address {address}: no Ray cluster answered within {RAY_CONNECT_SECONDS:.0f} s ({error})"
        ) from None


def _exit_on_sigterm(signum: int, frame: Any) -> None:
    raise SystemExit(128 + signum)


def check_sweep_folder(out: Path, experiment: Any) -> None:
    """``--out`` may take this sweep: no other process holds its lock, it is new, empty or a
    sweep's folder (:func:`~sb3_pm.commands.run_folder.sweep_folder_problem`), and a sweep's
    folder holds this very experiment (to resume it).

    :raises UsageError: naming the folder and what to do.
    """
    import yaml

    from sb3_pm.commands.run_folder import SWEEP_RECORD, in_use_message, lock_owner, sweep_folder_problem
    from sb3_pm.errors import UsageError
    from sb3_pm.experiments.runner import experiment_record

    owner = lock_owner(out) if out.is_dir() else None
    if owner is not None:
        raise UsageError(in_use_message(out, owner))
    problem = sweep_folder_problem(out)
    if problem is not None:
        raise UsageError(problem)
    record = out / SWEEP_RECORD
    if record.is_file():
        try:
            previous = yaml.safe_load(record.read_text())
        except yaml.YAMLError as error:
            raise UsageError(f"{record} is not valid YAML ({error}); choose another --out") from None
        if previous != yaml.safe_load(yaml.safe_dump(experiment_record(experiment), sort_keys=False)):
            raise UsageError(
                f"{out} holds a different experiment ({record}); resume with the same file and flags, "
                "or choose another --out"
            )


def check_cells_memory(experiment: Any, args: argparse.Namespace) -> None:
    """The sweep's memory check (:func:`~sb3_pm.experiments.memory_needs.check_sweep_memory`) on
    the cells still to run, before anything is written."""
    from sb3_pm.experiments.backends import default_jobs
    from sb3_pm.experiments.memory_needs import check_sweep_memory
    from sb3_pm.experiments.runner import plan_cells

    cells = plan_cells(experiment, args.out, device=args.device, update_device=args.update_device)
    todo = [cell for cell in cells if not cell.done]
    check_sweep_memory(todo, args.backend, args.jobs or default_jobs(), experiment.name)


def run(args: argparse.Namespace) -> int:
    from sb3_pm.commands.options import check_device, check_seeds
    from sb3_pm.commands.run_folder import RunFolderError, held_lock
    from sb3_pm.errors import UsageError
    from sb3_pm.experiments import load_experiment, reproduce
    from sb3_pm.graphs import resolve_graph

    experiment = load_experiment(args.experiment)
    if args.quick:
        experiment = experiment.quick()
    if args.graphs:
        experiment = experiment.with_graphs(args.graphs)
    if args.seeds:
        experiment = replace(experiment, seeds=tuple(args.seeds))
    if args.variants:
        known = [variant.key for variant in experiment.variants]
        unknown = [key for key in args.variants if key not in known]
        if unknown:
            raise UsageError(f"--variants: unknown variant(s) {unknown}; {args.experiment} has {known}")
        experiment = replace(
            experiment, variants=tuple(v for v in experiment.variants if v.key in set(args.variants))
        )
    if args.timesteps is not None:
        if args.timesteps < 1:
            raise UsageError(f"--timesteps must be at least 1, got {args.timesteps}")
        # Every learned variant's budget, its own included (a variant's ``timesteps`` key).
        variants = tuple(replace(v, timesteps=None) for v in experiment.variants)
        experiment = replace(experiment, timesteps=args.timesteps, variants=variants)
    for graph in experiment.graphs:
        resolve_graph(graph)  # every graph checked before hours of training start
    if args.jobs is not None and args.jobs < 1:
        raise UsageError(f"--jobs must be at least 1, got {args.jobs}")
    check_seeds(args.seeds or [], "--seeds")
    check_device(args.device, "--device")
    check_tracking(args)
    if args.ray_address and args.backend != "ray":
        raise UsageError("--ray-address needs --backend ray")
    if args.backend == "ray":
        check_ray(args.ray_address)
    if args.out.exists() and not args.out.is_dir():
        raise UsageError(f"--out {args.out} exists and is not a directory")
    if args.update_device is not None:  # before the folder is created and hours of training start
        from sb3_pm.experiments.preflight import check_update_device_takers
        from sb3_pm.experiments.runner import plan_cells

        cells = plan_cells(experiment, args.out, device=args.device, update_device=args.update_device)
        check_update_device_takers(args.update_device, cells)
    check_sweep_folder(args.out, experiment)  # before the folder is created: a refusal leaves nothing
    check_cells_memory(experiment, args)  # likewise, before the lock file creates the folder
    args.out.mkdir(parents=True, exist_ok=True)
    # SIGTERM ends the sweep like Ctrl-C: the workers are terminated with it (a SIGKILLed parent's
    # workers notice on their own, see sb3_pm.experiments.backends.exit_with_parent).
    signal.signal(signal.SIGTERM, _exit_on_sigterm)
    try:
        with held_lock(args.out):  # the whole sweep: a second one on --out is refused, not run twice
            check_sweep_folder(args.out, experiment)  # again, now that no other sweep can write it
            comparison = reproduce(
                experiment,
                args.out,
                backend=args.backend,
                n_jobs=args.jobs,
                ray_address=args.ray_address,
                progress=not args.no_progress,
                command=getattr(args, "command_line", None),
                device=args.device,
                update_device=args.update_device,
                tracking=tracking_of(args, group=experiment.name),
            )
    except RunFolderError as error:
        raise UsageError(str(error)) from None
    from sb3_pm.evaluation import markdown_table

    print(markdown_table(comparison.table))
    print(f"\nresults written to {args.out}/results.md (and .csv, .tex, anova.txt, plots)")
    return 0
