"""``sb3-pm evaluate``: run one policy on one graph and print its aggregate metrics."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from sb3_pm.commands.acting_options import (
    BOUND_AUTO,
    BOUND_OFF,
    acting_rule,
    add_switch_options,
    apply_neglect_bound,
    apply_switches,
    apply_temperature,
    neglect_bound_option,
    resolve_auto_bound,
    switch_notices,
)
from sb3_pm.commands.interrupts import sigterm_as_interrupt
from sb3_pm.commands.options import add_compute_options, check_compute_options, check_seeds, check_writable
from sb3_pm.files import write_atomic

#: ``--settling`` given without SINCE. Not a string, which argparse would pass through ``type=int``,
#: and not an int, so that ``--settling -1`` is refused like any other value out of range.
SECOND_HALF = object()

#: Runs with at least this many steps in all report progress (a bar on a terminal, lines elsewhere).
PROGRESS_MIN_STEPS = 5000
#: Team size for a rule-based policy (a trained team deploys with its own size by default).
DEFAULT_AGENTS = 4


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "evaluate",
        help="evaluate a baseline or a trained team",
        description="Run a policy for several episodes and print the mean and SD of every metric.",
    )
    parser.add_argument("--policy", required=True, help="a baseline name or a saved trained team directory")
    parser.add_argument(
        "--graph",
        default="paper-50",
        help="a preset (paper-50/100/200, er-50/100/200, rgg-60, rooms-4, cliques-6x8, karate; large "
        "sites city-1k/5k/20k, warehouse-1k/5k, campus-1k/5k) or a .graphml path (default paper-50); "
        "a team trained on another graph runs if its parameters do not depend on N",
    )
    parser.add_argument(
        "--agents",
        type=int,
        default=None,
        help="team size (default: a trained team's own size; 4 for a rule-based policy)",
    )
    parser.add_argument("--steps", type=int, default=500, help="episode length K (default 500)")
    parser.add_argument("--episodes", type=int, default=10, help="number of episodes (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="episode e uses env seed SEED + e (default 0)")
    parser.add_argument(
        "--json", type=Path, metavar="FILE", help="write episodes, mean, std and config as JSON"
    )
    parser.add_argument("--gif", type=Path, metavar="FILE", help="save the first episode as an animated GIF")
    acting = parser.add_mutually_exclusive_group()
    acting.add_argument(
        "--deterministic",
        action="store_true",
        help="take each agent's most likely allowed node, whatever the team's deploy_temperature",
    )
    acting.add_argument(
        "--stochastic",
        action="store_true",
        help="sample a learned team's actions from its trained distribution (temperature 1; seeded, "
        "reproducible)",
    )
    acting.add_argument(
        "--temperature",
        type=float,
        metavar="T",
        help="sample a learned team's actions from softmax(logits / T) over the allowed nodes "
        "(T < 1 is closer to the most likely action). Without any of these three a team acts by "
        "its config's deploy_temperature, saved with it (most likely action unless it set one)",
    )
    parser.add_argument(
        "--neglect-bound",
        type=neglect_bound_option,
        metavar="B",
        help="deploy a trained DCBF team with the filter's neglect bound B (rule 8) instead of its own "
        "setting (its config's deploy_filter, saved with it), 'off' to act with none, or 'auto': a "
        "territory bound calibrated on this graph, the worst peak uncertainty of "
        "territory_patrol over 10 episodes of its own, none where that rule lets a target reach "
        "u_max; prints how often the bound forced the agents' moves",
    )
    parser.add_argument(
        "--fail",
        action="append",
        default=[],
        metavar="AGENT:STEP",
        help="agent AGENT fails after step STEP (repeatable), e.g. --fail agent_1:250",
    )
    parser.add_argument(
        "--failure-rate",
        type=float,
        default=0.0,
        metavar="P",
        help="each live agent fails after any step with probability P",
    )
    parser.add_argument(
        "--neglect-scope",
        choices=["known", "unserved", "territory"],
        default=None,
        help="with --neglect-bound: bound every known target (known), only those last seen without a "
        "teammate on them (unserved), or the targets of each agent's own territory (territory); "
        "default: the scope of the team's own bound (its deploy_filter's), else known",
    )
    add_switch_options(parser)
    parser.add_argument(
        "--settling",
        nargs="?",
        type=int,
        const=SECOND_HALF,
        default=None,
        metavar="SINCE",
        help="print where each agent settles in each episode (the nodes it stood on for a share of "
        "the steps after the first SINCE; default: the second half) and which targets nobody "
        "holds; saved in --json",
    )
    parser.add_argument(
        "--layout",
        choices=["dense", "edges"],
        default=None,
        help="the env's observation layout: dense (N x N adjacencies) or edges (edge lists, for sites "
        "of thousands of nodes); a trained team's policies are rebuilt for it (default: the team's own, "
        "else dense)",
    )
    parser.add_argument(
        "--territories",
        # TERRITORY_CONVENTIONS, written out: importing the planner would slow every command's start
        choices=["split", "planned", "planned_tours"],
        default=None,
        help="the territory convention of a team told its territory or the rule's move: split, planned "
        "(the plan's groups for each episode's starts) or planned_tours (the same, groups the plan walks "
        "as tours walked so); default: the team's own",
    )
    parser.add_argument("--no-progress", action="store_true", help="never show progress")
    add_compute_options(parser)
    parser.set_defaults(func=run)


def check_counts(args: argparse.Namespace) -> None:
    """Reject non-positive sizes with one clear line before any work starts."""
    from sb3_pm.errors import UsageError

    for flag in ("agents", "steps", "episodes"):
        value = getattr(args, flag)
        if value is not None and value < 1:
            raise UsageError(f"--{flag} must be at least 1, got {value}")
    if getattr(args, "seed", None) is not None:
        check_seeds([args.seed], "--seed")
    check_seeds(getattr(args, "seeds", None) or [], "--seeds")
    settling = getattr(args, "settling", None)
    if settling is not None and settling is not SECOND_HALF and not 0 <= settling < args.steps:
        raise UsageError(
            f"--settling SINCE must be in [0, {args.steps}) for {args.steps}-step episodes, got {settling}"
        )


def check_evaluation_memory(
    policy: str, graph: Any, n_agents: int | None, name: str, layout: str | None = None
) -> None:
    """Refuse, from sizes alone, an evaluation too large for this host's memory, before the team
    loads (a saved team builds its training env copies as it loads) and before any env is built.

    :param n_agents: the team size asked for (``None``: a saved team's own, else the default).
    :param layout: ``--layout`` (``edges``: the env and the forward pass count edges, not pairs).
    """
    from sb3_pm.agents.deployment.saved_teams import MANIFEST, read_manifest
    from sb3_pm.baselines import BASELINES
    from sb3_pm.zoo.memory import check_memory, dense_attention, evaluation_estimate

    manifest: dict[str, Any] = {}
    if policy not in BASELINES:
        from sb3_pm.pretrained import PREFIX, pretrained_path

        where = pretrained_path(policy) if policy.startswith(PREFIX) else Path(policy)
        folder = where if (where / MANIFEST).is_file() else where / "team"
        try:
            manifest = read_manifest(folder)
        except (OSError, ValueError):
            pass  # the loader says what is wrong with it
    agents = n_agents or int(manifest.get("n_agents") or DEFAULT_AGENTS)
    estimate = evaluation_estimate(
        graph.n_nodes,
        agents,
        policy not in BASELINES,
        dense_attention=dense_attention(graph, None),
        team_envs=int(manifest.get("n_envs") or 0),
        edges=2 * graph.n_edges if layout == "edges" else None,
    )
    check_memory(estimate, f"evaluating {policy} ({agents} agents) on {name}")


def settle_since(args: argparse.Namespace) -> int | None:
    """The harness's ``settle_since`` from ``--settling [SINCE]`` (bare: the second half)."""
    if args.settling is None:
        return None
    return args.steps // 2 if args.settling is SECOND_HALF else int(args.settling)


def check_territories_option(args: argparse.Namespace, team: Any) -> None:
    """``--territories`` needs a team told its territory or the rule's move: a one-line
    :class:`UsageError` for any other."""
    from sb3_pm.errors import UsageError

    settings = team.env_settings()
    if args.territories is not None and not (settings.get("territory_input") or settings.get("advice_input")):
        raise UsageError(
            f"--territories sets the convention of a team told its territory or the rule's move, and "
            f"{args.policy} is told neither; a rule's convention is in its name (territory_patrol, "
            "planned_patrol, planned_tour_patrol)"
        )


def env_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The env settings the command line puts over the team's own: ``--layout``, ``--territories``,
    ``--fail`` and ``--failure-rate``."""
    from sb3_pm.errors import UsageError

    failures: dict[str, int] = {}
    for item in args.fail:
        agent, _, step = item.rpartition(":")
        if not agent or not step.lstrip("-").isdigit():
            raise UsageError(f"--fail takes AGENT:STEP (e.g. agent_1:250), got {item!r}")
        if agent in failures:
            raise UsageError(f"--fail names {agent} twice")
        failures[agent] = int(step)
    kwargs: dict[str, Any] = {}
    if getattr(args, "layout", None) is not None:  # over the team's own (a trained team was rebuilt for it)
        kwargs["layout"] = args.layout
    if getattr(args, "territories", None) is not None:  # over the team's own convention
        kwargs["territories"] = args.territories
    if failures:
        kwargs["failures"] = failures
    if args.failure_rate:
        kwargs["failure_rate"] = args.failure_rate
    return kwargs


def print_summary(result: Any, stream: Any = None) -> None:
    """The aggregate table: one row per metric, mean and SD over the episodes."""
    stream = stream or sys.stdout
    mean, std = result.mean, result.std
    steps = result.config["max_cycles"]
    title = f"{result.policy} on {result.graph}: {len(result.episodes)} episodes x {steps} steps"
    try:
        from rich.console import Console
        from rich.table import Table
    except ImportError:  # rich is optional; plain text says the same
        print(title, file=stream)
        for name in mean:
            print(f"  {name:<20} {mean[name]:>12.3f} ± {std[name]:.3f}", file=stream)
        return
    print(title, file=stream)
    table = Table()
    table.add_column("metric")
    table.add_column("mean", justify="right")
    table.add_column("sd", justify="right")
    for name in mean:
        table.add_row(name, f"{mean[name]:.3f}", f"{std[name]:.3f}")
    Console(file=stream, width=100).print(table)


def record_run(result: Any, args: argparse.Namespace, team: Any, acting_filter: Any, calibration: Any) -> Any:
    """Put the graph as given, how often the filter forced moves and a calibrated bound into the
    result's config (evaluate() recorded the bound the team acted under, if any); returns the
    filter activity, or None."""
    result.config["graph"] = str(args.graph)
    activity = team.filter_activity() if acting_filter is not None else None
    if activity is not None:
        result.config["filter_activity"] = activity
    if calibration is not None:
        result.config["neglect_calibration"] = calibration.to_dict()
    return activity


def keep_partial(args: argparse.Namespace, stop: Any) -> int:
    """Ctrl-C or SIGTERM during the episodes: print the finished ones' summary, write them to
    ``--json`` marked partial (``"partial": true``, ``"episodes_finished"``; a file that had none
    is left as it was), say so in one line, and return the interrupt's exit status (130, 143)."""
    result = stop.result
    finished, requested = len(result.episodes), result.episodes_requested
    if finished:
        print_summary(result)
    if args.json is None:
        kept = "no --json given to keep them" if finished else "nothing to keep"
    elif not finished:
        kept = f"{args.json} left as it was"
    else:
        write_atomic(args.json, json.dumps(result.to_dict(), indent=2))
        kept = f"wrote them to {args.json}, marked partial"
    print(f"sb3-pm evaluate: interrupted after {finished} of {requested} episodes; {kept}", file=sys.stderr)
    return int(stop.exit_status)


def run(args: argparse.Namespace) -> int:
    from sb3_pm.errors import InputError, UsageError
    from sb3_pm.evaluation import EvaluationInterrupted, evaluate, policy_label, record_gif, resolve_team
    from sb3_pm.graphs import resolve_graph

    check_counts(args)
    check_compute_options(args)
    graph = resolve_graph(args.graph)  # fail on a bad graph before loading a model
    check_writable(args.json, "--json")  # before the evaluation, whose result it would lose
    check_writable(args.gif, "--gif")
    if args.neglect_scope is not None and args.neglect_bound in (None, BOUND_OFF):
        raise UsageError("--neglect-scope needs --neglect-bound B")
    if args.temperature is not None:
        from sb3_pm.policies.sampling import check_temperature

        try:
            check_temperature(args.temperature)  # before the team loads
        except InputError:
            raise UsageError(f"--temperature must be positive and finite, got {args.temperature}") from None
    check_evaluation_memory(args.policy, graph, args.agents, str(args.graph), args.layout)
    team = resolve_team(args.policy, graph=graph, device=args.device, layout=args.layout)
    check_territories_option(args, team)
    if args.agents is None:  # a trained team deploys as it was trained unless told otherwise
        args.agents = team.n_agents or DEFAULT_AGENTS
    calibration = None
    if args.neglect_bound is None and team.site_bound_pending:
        args.neglect_bound = BOUND_AUTO  # its deploy_filter: the bound this site allows
        print("the team's deploy_filter is auto: calibrating its territory bound here", file=sys.stderr)
    if args.neglect_bound == BOUND_AUTO:  # the site's own bound, from the team's env settings
        calibration = resolve_auto_bound(args, team, graph, team.env_settings())
    else:
        apply_neglect_bound(team, args.neglect_bound, args.neglect_scope)
    apply_switches(team, args, graph, {**team.env_settings(), **env_overrides(args)})  # as deployed
    apply_temperature(team, args.temperature, args.stochastic)
    label = policy_label(args.policy, team)
    acting_filter = team.acting_filter()  # after the flags
    trained_agents = team.n_agents
    if trained_agents is not None and trained_agents != args.agents:
        if not team.resizable:
            raise UsageError(
                f"the team in {args.policy} has {trained_agents} agents and cannot be deployed with "
                f"another number; pass --agents {trained_agents}"
            )
        print(
            f"deploying the {trained_agents}-agent team with {args.agents} agents: agent_i acts with "
            f"learner agent_(i mod {trained_agents})",
            file=sys.stderr,
        )
        if acting_filter is not None and acting_filter["neglect_scope"] == "territory":
            print(
                f"its territory bound keeps the {trained_agents}-way split: "
                + (
                    "the territories of the missing learners have no bound"
                    if args.agents < trained_agents
                    else "agents that share a learner share its territory"
                ),
                file=sys.stderr,
            )
    env_kwargs = env_overrides(args)  # over the team's own env settings (evaluate() adds them)
    long_run = args.episodes * args.steps >= PROGRESS_MIN_STEPS
    deterministic = acting_rule(args)
    if args.neglect_bound is None and acting_filter is not None:
        print(
            f"the team acts under its deploy_filter: neglect bound {acting_filter['neglect_bound']:g}, scope "
            f"{acting_filter['neglect_scope']} (--neglect-bound off to act without it)",
            file=sys.stderr,
        )
    for notice in switch_notices(team, args):
        print(notice, file=sys.stderr)
    own_temperature = team.deploy_temperature
    if deterministic is None and own_temperature is not None:
        print(
            f"the team samples its actions at its deploy_temperature {own_temperature:g} "
            "(--deterministic for the most likely action)",
            file=sys.stderr,
        )
    try:
        with sigterm_as_interrupt():
            result = evaluate(
                team,
                graph,
                n_agents=args.agents,
                episodes=args.episodes,
                seed=args.seed,
                max_cycles=args.steps,
                env_kwargs=env_kwargs,
                progress=None if long_run and not args.no_progress else False,
                policy_name=label,
                deterministic=deterministic,
                threads=args.threads,
                settle_since=settle_since(args),
            )
    except EvaluationInterrupted as stop:
        record_run(stop.result, args, team, acting_filter, calibration)
        return keep_partial(args, stop)
    activity = record_run(result, args, team, acting_filter, calibration)
    print_summary(result)
    if activity is not None:
        share = activity["forced"] / max(1, activity["masks"])
        bound = result.config["neglect_bound"]
        print(f"neglect bound {bound:g}: forced {share:.1%} of {activity['masks']} agent-steps")
    if args.settling is not None:
        from sb3_pm.evaluation.settling import MIN_SHARE, settling_table

        since = result.episodes[0].settling.since  # type: ignore[union-attr]  # settle_since was set
        print(
            f"where each agent settles in steps {since + 1}-{args.steps} "
            f"(nodes held >= {MIN_SHARE:.0%} of them):"
        )
        print(settling_table(result.episodes))
    if args.json is not None:
        write_atomic(args.json, json.dumps(result.to_dict(), indent=2))
        print(f"wrote {args.json}", file=sys.stderr)
    if args.gif is not None:
        gif_team = resolve_team(args.policy, graph=graph, device=args.device, layout=args.layout)
        apply_neglect_bound(gif_team, args.neglect_bound, args.neglect_scope)
        apply_switches(gif_team, args)
        apply_temperature(gif_team, args.temperature, args.stochastic)
        with sigterm_as_interrupt():  # a stopped GIF leaves the previous file, and no temporary one
            record_gif(
                gif_team,
                graph,
                args.gif,
                n_agents=args.agents,
                seed=args.seed,
                max_cycles=args.steps,
                env_kwargs=env_kwargs,
                deterministic=deterministic,
                threads=args.threads,
            )
        print(f"wrote {args.gif}", file=sys.stderr)
    return 0
