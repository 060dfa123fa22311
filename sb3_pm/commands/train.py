"""``sb3-pm train``: train an independent-learner team from an rl-zoo style config.

::

    sb3-pm train [--config ippo] --env paper-50 --seed 0 [--timesteps T] [--out DIR]
    sb3-pm train --resume DIR

``--config`` defaults to the shipped ``ippo`` config (the repository's ``zoo/ippo.yml``), the best
configuration measured; ``--config ippo_paper`` trains the paper-faithful one.

The run folder (default ``runs/<graph>_<algo>_s<seed>``, relative to the working directory)
records ``config.yml`` (the resolved entry), ``args.yml``, ``command.txt``, ``machine.yml`` (the CPU
and library versions it ran on), TensorBoard logs per
agent in ``tb/``, checkpoints in ``checkpoints/`` and the saved team in ``team/`` (what
``sb3-pm evaluate --policy RUN_DIR`` loads).

Checkpoints (every ``--checkpoint-every`` rollouts, the newest two kept) hold everything the run
depends on, so ``--resume DIR`` continues an interrupted run bit for bit: its final team equals the
one an uninterrupted run would have saved. Ctrl-C (or SIGTERM) lets the team finish its current
rollout, writes a checkpoint and exits with status 130; a second Ctrl-C exits at once, keeping the
last periodic checkpoint.
"""

from __future__ import annotations

import argparse
import shlex
import time
from pathlib import Path
from typing import Any

import yaml

from sb3_pm.commands.interrupts import sigterm_as_interrupt
from sb3_pm.commands.options import add_compute_options, check_device
from sb3_pm.commands.run_folder import (
    RunFolderError,
    contents_problem,
    in_use_message,
    lock_owner,
    locked_run_folder,
    save_final_team,
)
from sb3_pm.commands.tracking import add_tracking_options, check_tracking, tracked
from sb3_pm.errors import InputError
from sb3_pm.files import append_atomic, write_atomic
from sb3_pm.machine import write_machine_record


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "train",
        help="train an independent PPO team from a YAML config",
        description="Train one learner per agent (sharing nothing) and save the team to a run folder.",
    )
    parser.add_argument(
        "--config",
        default=None,
        help="rl-zoo style YAML: a path, or the name of a shipped config (ippo, ippo_split, ippo_paper, "
        "ippo_improved, ippo_transfer, ippo_transfer_prior4, ippo_transfer_split). "
        "Default: ippo, the package's copy of zoo/ippo.yml, the best configuration measured "
        "(docs/RESULTS.md); ippo_paper is the paper-faithful one",
    )
    parser.add_argument(
        "--env",
        default=None,
        help="a preset (paper-50/100/200: the paper's published graphs; er-50/100/200: seeded "
        "Erdős–Rényi draws; rgg-60, rooms-4, cliques-6x8, karate: other structures; city-1k/5k/20k, "
        "warehouse-1k/5k, campus-1k/5k: large sites), a .graphml "
        "path, or a graph family that draws a new graph each episode (family:er, family:rgg, "
        "family:rooms, family:mixed, or family:FOLDER of .graphml files). Default: the config's "
        "env, else paper-50",
    )
    parser.add_argument(
        "--seed", type=int, default=None, help="seeds the env copies and every learner (default 0)"
    )
    parser.add_argument(
        "--timesteps", type=int, metavar="T", help="steps per learner (default: the config's n_timesteps)"
    )
    parser.add_argument("--n-envs", type=int, metavar="N", help="env copies (default: the config's n_envs)")
    parser.add_argument(
        "--out", type=Path, metavar="DIR", help="run folder (default runs/<graph>_<algo>_s<seed>)"
    )
    parser.add_argument(
        "--hyperparams",
        nargs="+",
        default=[],
        metavar="KEY:VALUE",
        help="override entries of the config, rl-zoo style; VALUE is YAML, e.g. learning_rate:1e-4 "
        "'policy_kwargs:{avoid_collisions: true}' (policy_kwargs and env_kwargs merge key by key)",
    )
    parser.add_argument(
        "--env-kwargs",
        nargs="+",
        default=[],
        metavar="KEY:VALUE",
        help="override environment arguments, e.g. reward:reduction max_cycles:200",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an existing run folder")
    parser.add_argument(
        "--checkpoint-every",
        type=int,
        default=None,
        metavar="N",
        help=f"write a checkpoint every N rollouts into DIR/checkpoints (default {DEFAULT_CHECKPOINT_EVERY}; "
        "0: none, then Ctrl-C keeps nothing)",
    )
    parser.add_argument(
        "--resume",
        type=Path,
        metavar="DIR",
        help="continue the interrupted run in DIR from its newest checkpoint, with the settings recorded "
        "in DIR/args.yml, device, threads and checkpoint interval included (give no other training option)",
    )
    parser.add_argument("--verbose", type=int, default=0, help="SB3 verbosity of every learner (default 0)")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    add_compute_options(parser, training=True)
    add_tracking_options(parser)
    parser.set_defaults(func=run)


#: Default ``--checkpoint-every``: at the paper's budget (100 rollouts) about one checkpoint a minute.
DEFAULT_CHECKPOINT_EVERY = 10
#: Options that define a run; ``--resume`` takes them from the run folder instead.
RUN_OPTIONS = ("config", "env", "seed", "timesteps", "n_envs", "out", "hyperparams", "env_kwargs")


def _package_dir() -> Path:
    import sb3_pm

    return Path(sb3_pm.__file__).resolve().parent


def check_run_folder(out: Path, overwrite: bool) -> None:
    """Everything about ``out`` that can be checked without touching it, before any work starts."""
    from sb3_pm.errors import UsageError

    resolved = out.resolve()
    if resolved == _package_dir() or _package_dir() in resolved.parents:
        raise UsageError(
            f"run folder {out} is inside the sb3_pm package; choose a folder outside the source tree"
        )
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out} exists and is not a folder")
    owner = lock_owner(out) if out.is_dir() else None
    if owner is not None:
        raise UsageError(in_use_message(out, owner))
    problem = contents_problem(out, overwrite)
    if problem is not None:
        raise UsageError(problem)
    parent = next((p for p in (out, *out.parents) if p.exists()), Path("."))
    if not parent.is_dir():
        raise UsageError(f"cannot create run folder {out}: {parent} is not a folder")


def run(args: argparse.Namespace) -> int:
    from sb3_pm.errors import UsageError
    from sb3_pm.graphs import GraphFamily, graph_label, resolve_graph_or_family
    from sb3_pm.zoo import load_config
    from sb3_pm.zoo.checks import check_batch
    from sb3_pm.zoo.config import default_env
    from sb3_pm.zoo.memory import check_memory, config_estimate

    if args.resume is not None:
        return resume(args)
    args.config = args.config or "ippo"
    args.env = args.env or default_env(args.config) or "paper-50"
    args.seed = 0 if args.seed is None else args.seed
    if args.checkpoint_every is None:
        args.checkpoint_every = DEFAULT_CHECKPOINT_EVERY
    for flag in ("timesteps", "n_envs", "threads"):
        value = getattr(args, flag)
        if value is not None and value < 1:
            raise UsageError(f"--{flag.replace('_', '-')} must be at least 1, got {value}")
    if args.seed < 0:
        raise UsageError(f"--seed must be at least 0, got {args.seed}")
    check_device(args.device, "--device")
    check_tracking(args)
    if args.checkpoint_every < 0:
        raise UsageError(f"--checkpoint-every must be at least 0, got {args.checkpoint_every}")
    graph = resolve_graph_or_family(args.env)
    overrides = parse_overrides(args.hyperparams, "--hyperparams")
    if "env" in overrides:
        raise UsageError("--hyperparams env:... is not read; name the graph or family with --env")
    env_overrides = parse_overrides(args.env_kwargs, "--env-kwargs")
    if env_overrides:
        overrides["env_kwargs"] = {**overrides.get("env_kwargs", {}), **env_overrides}
    config = load_config(args.config, args.env, overrides)
    if args.timesteps is not None:
        config.n_timesteps = args.timesteps
    if args.n_envs is not None:
        config.n_envs = args.n_envs
        for agent, values in [("", {}), *config.agents.items()]:  # batch_size was checked for another rollout
            where = f"{config.source}: {config.entry}{f'.agents.{agent}' if agent else ''} (with --n-envs)"
            check_batch({**config.hyperparams, **values}, config.n_envs, where)
    # sizes only: a graph too large for this host is refused before any folder or env exists
    check_memory(config_estimate(config, graph), f"training {config.n_agents} agents on {args.env}")
    out = args.out or Path("runs") / f"{graph_label(args.env)}_{config.algo}_s{args.seed}"
    # Everything is checked, and the team built (which validates policy_kwargs, the team size and
    # every learner argument), before the run folder is created or emptied: a bad run leaves nothing.
    check_run_folder(out, args.overwrite)
    import torch

    # Measured: two runs with the same seed gave different parameters with torch's default 2 threads
    # on 2 cores, and identical ones with 1 thread.
    torch.set_num_threads(args.threads)
    from sb3_pm.agents.training.team import IndependentPPO

    try:
        team = IndependentPPO.from_config(
            config,
            graph,
            seed=args.seed,
            tensorboard_log=out / "tb",
            verbose=args.verbose,
            device=args.device,
        )
    except TypeError as error:  # an argument the algorithm or the policy does not take
        raise UsageError(f"{config.source}: {error}") from None
    try:
        team.update_device = args.update_device
    except InputError as error:
        team.close()
        raise UsageError(str(error)) from None
    try:
        with locked_run_folder(out, args.overwrite):
            _write_records(args, config, out)
            size = (
                f"a new graph each episode, {graph.min_nodes} to {graph.max_nodes} nodes"
                if isinstance(graph, GraphFamily)
                else f"{graph.n_nodes} nodes, {graph.n_targets} targets"
            )
            print(
                f"training {config.n_agents} x {config.algo} on {graph.name} ({size}), "
                f"{config.n_timesteps} steps per learner, config entry {config.entry!r} -> {out}"
            )
            if config.learning_rate_spread != 1.0:
                rates = ", ".join(
                    f"{agent} {values['learning_rate']:.3g}"
                    if isinstance(values["learning_rate"], float)
                    else f"{agent} {values['learning_rate']}"
                    for agent, values in config.per_agent().items()
                )
                print(f"learning rates (learning_rate_spread {config.learning_rate_spread:g}): {rates}")
            with tracked(args, out, {"env": str(args.env), "seed": args.seed, **config.to_dict()}):
                return _learn_and_save(team, config.n_timesteps, args, out, args.checkpoint_every, args.env)
    except RunFolderError as error:
        raise UsageError(str(error)) from None
    finally:
        team.close()


def resume(args: argparse.Namespace) -> int:
    """``--resume DIR``: continue the run in DIR from its newest intact checkpoint."""
    from sb3_pm.agents.training.checkpoints import CheckpointError
    from sb3_pm.agents.training.team import MANIFEST, IndependentPPO
    from sb3_pm.errors import UsageError

    given = [f"--{name.replace('_', '-')}" for name in RUN_OPTIONS if getattr(args, name) not in (None, [])]
    if args.overwrite:
        given.append("--overwrite")
    if args.checkpoint_every is not None:
        given.append("--checkpoint-every")
    # the run's own are used: the same arithmetic
    for flag, changed in (("--device", args.device != "cpu"), ("--threads", args.threads != 1)):
        if changed:
            given.append(flag)
    if given:
        raise UsageError(
            f"--resume continues the run recorded in {args.resume}/args.yml; drop {', '.join(given)}"
        )
    out: Path = args.resume
    if not (out / "args.yml").is_file():
        raise UsageError(f"{out} is not a run folder of sb3-pm train (no args.yml)")
    if (out / "team" / MANIFEST).is_file():
        raise UsageError(
            f"the run in {out} has finished (its team is saved in {out / 'team'}); nothing to resume"
        )
    owner = lock_owner(out)
    if owner is not None:
        raise UsageError(in_use_message(out, owner))
    try:
        recorded = yaml.safe_load((out / "args.yml").read_text())
    except yaml.YAMLError as error:
        raise UsageError(f"{out / 'args.yml'} is not valid YAML ({error})") from None
    if not isinstance(recorded, dict):
        raise UsageError(f"{out / 'args.yml'} is not a record of sb3-pm train's arguments")
    threads, device = recorded.get("threads", 1), str(recorded.get("device", "cpu"))
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise UsageError(f"{out / 'args.yml'}: threads must be an integer of at least 1, got {threads!r}")
    check_device(device, f"{out / 'args.yml'}: device")
    import torch

    torch.set_num_threads(threads)  # the interrupted run's: same arithmetic
    try:
        team = IndependentPPO.from_checkpoint(
            out, device=device, tensorboard_log=out / "tb", verbose=args.verbose
        )
    except CheckpointError as error:
        raise UsageError(f"cannot resume {out}: {error}; start again with --overwrite") from None
    # Where the updates run may change on resuming (a GPU run cut off, continued without one): the
    # command line, kept in resumed.txt, says so; unless given, the run's own is used.
    update_device = args.update_device if args.update_device is not None else recorded.get("update_device")
    try:
        team.update_device = update_device
    except InputError as error:
        team.close()
        raise UsageError(
            f"cannot resume {out}: {error}; give --update-device cpu to update on the CPU"
        ) from None
    every = int(recorded.get("checkpoint_every", DEFAULT_CHECKPOINT_EVERY))
    try:
        with locked_run_folder(out, overwrite=False, resume=True):
            line = (
                f"{time.strftime('%Y-%m-%dT%H:%M:%S')} resumed from {team.checkpoint} at step "
                f"{team.num_timesteps}: {shlex.join(args.command_line)}\n"
            )
            append_atomic(out / "resumed.txt", line)
            print(
                f"resuming {out} from {team.checkpoint}: {team.num_timesteps} steps per learner done, "
                f"{team.remaining_timesteps} to go"
            )
            return _learn_and_save(team, None, args, out, every, str(recorded.get("env", team.graph.name)))
    except RunFolderError as error:
        raise UsageError(str(error)) from None
    finally:
        team.close()


def _learn_and_save(
    team: Any, steps: int | None, args: argparse.Namespace, out: Path, every: int, graph: str
) -> int:
    """Train ``team`` for ``steps`` steps (``None``: to the end of the run it was restored from)
    with checkpoints, then save it to ``out/team``.

    :returns: the exit status: 0, or 130 when interrupted (after saying how to resume).
    """
    from sb3_pm.agents.training.checkpoints import CHECKPOINTS, CheckpointSchedule, TrainingInterrupted

    schedule = CheckpointSchedule(out / CHECKPOINTS, every=every) if every > 0 else None

    def tell() -> None:
        print(
            "\ninterrupt: finishing this rollout to write a checkpoint; interrupt again to stop now",
            flush=True,
        )

    try:
        with sigterm_as_interrupt():
            if steps is None:
                team.learn_remaining(schedule, progress_bar=not args.no_progress, on_interrupt=tell)
            else:
                team.learn(steps, progress_bar=not args.no_progress, checkpoints=schedule, on_interrupt=tell)
    except TrainingInterrupted as stop:
        print(f"interrupted at step {team.num_timesteps} per learner; checkpoint saved to {stop.checkpoint}")
        print(f"continue with: sb3-pm train --resume {out}")
        return 130
    except KeyboardInterrupt:
        last = None if schedule is None else schedule.last
        if last is None:
            print("interrupted before any checkpoint was written; nothing to resume")
        else:
            print(f"interrupted; the last checkpoint is {last}")
            print(f"continue with: sb3-pm train --resume {out}")
        return 130
    folder = save_final_team(team, out)  # a failed save keeps the training, for --resume
    print(f"team saved to {folder}")
    if graph.startswith("family:"):  # trained on no one graph: it is deployed on any
        graph = "paper-50"
    print(f"evaluate it with: sb3-pm evaluate --policy {out} --graph {graph}")
    return 0


def _write_records(args: argparse.Namespace, config: Any, out: Path) -> None:
    """``args.yml``, ``config.yml`` (the resolved entry), ``command.txt`` and ``machine.yml``
    (:func:`sb3_pm.machine.write_machine_record`), each written atomically."""
    recorded = {
        key: (str(value) if isinstance(value, Path) else value)
        for key, value in vars(args).items()
        if key != "func"
    }
    recorded["out"] = str(out)
    write_atomic(out / "args.yml", yaml.safe_dump(recorded, sort_keys=True))
    entry = config.to_dict()
    entry.pop("env", None)  # the graph or family trained on is the run's (--env or the config's)
    resolved = {"env": str(args.env), "entry": config.entry, "source": config.source, **entry}
    write_atomic(out / "config.yml", yaml.safe_dump(resolved, sort_keys=False))
    # The equivalent command (with every setting made explicit), to rerun this exact training.
    write_atomic(out / "command.txt", shlex.join(["sb3-pm", "train", *_argv_from(args, out)]) + "\n")
    # ... and what it ran on: the same command trains another team on another kind of CPU.
    write_machine_record(out)


def parse_overrides(items: list[str], flag: str) -> dict[str, Any]:
    """``["key:value", ...]`` -> ``{key: YAML-parsed value}`` (rl-zoo's ``--hyperparams`` syntax,
    with YAML instead of Python ``eval`` for the values)."""
    from sb3_pm.errors import UsageError

    parsed: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition(":")
        if not sep or not key.strip():
            raise UsageError(f"{flag}: expected KEY:VALUE, got {item!r}")
        try:
            parsed[key.strip()] = yaml.safe_load(text) if text.strip() else None
        except yaml.YAMLError as error:
            raise UsageError(f"{flag}: the value of {key!r} is not valid YAML ({error})") from None
        # deploy_temperature:null is the argmax rule and deploy_filter:null the filter as trained;
        # an empty value is a slip anywhere
        nullable = key.strip() in ("deploy_temperature", "deploy_filter")
        if parsed[key.strip()] is None and not (nullable and text.strip()):
            raise UsageError(f"{flag}: {key!r} has no value")
    return parsed


def _argv_from(args: argparse.Namespace, out: Path) -> list[str]:
    """The command line that reproduces this run (``command.txt``)."""
    argv = ["--config", str(args.config), "--env", str(args.env), "--seed", str(args.seed), "--out", str(out)]
    for flag, value in (("--timesteps", args.timesteps), ("--n-envs", args.n_envs)):
        if value is not None:
            argv += [flag, str(value)]
    if args.hyperparams:
        argv += ["--hyperparams", *args.hyperparams]
    if args.env_kwargs:
        argv += ["--env-kwargs", *args.env_kwargs]
    if args.device != "cpu":
        argv += ["--device", args.device]
    if args.update_device is not None:
        argv += ["--update-device", args.update_device]
    if args.threads != 1:
        argv += ["--threads", str(args.threads)]
    if args.checkpoint_every != DEFAULT_CHECKPOINT_EVERY:
        argv += ["--checkpoint-every", str(args.checkpoint_every)]
    if args.overwrite:
        argv.append("--overwrite")
    return argv
