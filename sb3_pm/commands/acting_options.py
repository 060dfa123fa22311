"""``sb3-pm evaluate``'s acting-rule options: ``--neglect-bound`` (a number, ``off`` or ``auto``),
``--neglect-scope``, ``--leave-cleared``, ``--pass-held``, ``--keep-moving``, ``--visit-deadline``,
``--temperature``, ``--stochastic`` and ``--deterministic``, checked against the team and applied to it."""

from __future__ import annotations

import argparse
import sys
from typing import Any

#: ``--neglect-bound off``: act with no bound, whatever the team's deploy_filter says.
BOUND_OFF = "off"
#: ``--neglect-bound auto``: the territory bound calibrated on the site
#: (:mod:`sb3_pm.evaluation.neglect_calibration`).
BOUND_AUTO = "auto"


def neglect_bound_option(text: str) -> float | str:
    """``--neglect-bound``'s value: a number, ``off`` or ``auto``."""
    word = text.strip().lower()
    if word in (BOUND_OFF, BOUND_AUTO):
        return word
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, 'off' or 'auto', got {text!r}") from None


def require_filter(team: Any, option: str = "--neglect-bound") -> None:
    """``option`` (a rule of the DCBF filter) needs a team with the filter (a trained DCBF team)."""
    from sb3_pm.errors import UsageError

    if not team.learned:
        raise UsageError(f"{option} needs a trained DCBF team; {team.name!r} is not one")


def resolve_auto_bound(args: argparse.Namespace, team: Any, graph: Any, env_kwargs: dict[str, Any]) -> Any:
    """``--neglect-bound auto``: calibrate the territory bound on ``graph`` for the team's agents
    and set it on the team (:func:`~sb3_pm.evaluation.neglect_calibration.settle_site_bound`), and
    put the number (or ``off`` where the territories cannot be held) in ``args`` for the messages
    that follow. Returns the :class:`~sb3_pm.evaluation.neglect_calibration.CalibratedBound`.

    :param env_kwargs: the team's environment settings, without ``--fail``/``--failure-rate``
        (the bound is for the team as deployed, not as it fails).
    """
    from sb3_pm.errors import UsageError
    from sb3_pm.evaluation.neglect_calibration import settle_site_bound

    require_filter(team)
    if args.neglect_scope not in (None, "territory"):
        raise UsageError(
            f"--neglect-bound auto is a territory bound (calibrated on territory_patrol); "
            f"--neglect-scope {args.neglect_scope} cannot go with it"
        )
    trained = team.n_agents
    if trained is not None and trained != args.agents:
        # The bound keeps the trained team's split (agents that share a learner share its
        # territory), so a calibration on another split would measure other territories.
        raise UsageError(
            f"--neglect-bound auto calibrates the {trained}-agent team's territories; deploy it with "
            f"--agents {trained}, or give a number B (or off) for {args.agents} agents"
        )
    calibration = settle_site_bound(team, graph, args.agents, env_kwargs, max_cycles=args.steps)
    args.neglect_bound = BOUND_OFF if calibration.bound is None else calibration.bound
    args.neglect_scope = None if calibration.bound is None else "territory"
    print(calibration.describe(), file=sys.stderr)
    return calibration


def apply_neglect_bound(team: Any, bound: float | str | None, scope: str | None = None) -> None:
    """``--neglect-bound`` (and ``--neglect-scope``): set the filter's bound on a trained team, or
    switch it off (``"off"``); a baseline has no filter."""

    if bound is None:
        return
    require_filter(team)
    if bound == BOUND_OFF:
        team.set_filter(neglect_bound=None)
        return
    if scope is None:  # the team's own scope (its deploy_filter's), else known: said, not implied
        pending = team.site_bound_pending  # deploy_filter auto: a territory bound
        scope = "territory" if pending else (team.acting_filter() or {}).get("neglect_scope", "known")
    team.set_filter(neglect_bound=bound, neglect_scope=scope)


def apply_switch(team: Any, switch: str, choice: str | None) -> None:
    """``--leave-cleared``, ``--pass-held`` or ``--keep-moving on|off``: switch the filter's rule 9,
    10 or 11 (``switch``: one of :data:`~sb3_pm.policies.dcbf.FILTER_SWITCHES`) on a trained DCBF
    team; ``None``: as the team's deploy_filter says."""
    if choice is None:
        return
    require_filter(team, "--" + switch.replace("_", "-"))
    team.set_filter(**{switch: choice == "on"})


#: What each of the filter's switches does, said where a team's deploy_filter turns it on.
_SWITCH_NOTICES = {
    "leave_cleared": "rule 9, leave_cleared: an agent on a target it observes cleared moves on "
    "(--leave-cleared off to let it stay)",
    "pass_held": "rule 10, pass_held: an agent whose advised next node is held waits a step, then "
    "takes it (--pass-held off to act without it)",
    "keep_moving": "rule 11, keep_moving: an agent off targets advised on to a free node does not "
    "stay (--keep-moving off to act without it)",
}


#: Each filter switch's flag and what it does, for ``sb3-pm evaluate``'s help.
_SWITCH_HELP = {
    "leave_cleared": "the filter's rule 9 on a trained DCBF team: an agent on a target it observes "
    "cleared (u = 0) moves on instead of staying",
    "pass_held": "the filter's rule 10 on a trained DCBF team with advice_input: an agent off targets "
    "whose advised next node holds another agent waits a step, then takes it",
    "keep_moving": "the filter's rule 11 on a trained DCBF team with advice_input: an agent off targets "
    "advised on to a free node does not stay",
}


def add_switch_options(parser: argparse.ArgumentParser) -> None:
    """``--leave-cleared``, ``--pass-held`` and ``--keep-moving``, each ``on|off`` (default: as the
    team's deploy_filter says)."""
    for switch, help_text in _SWITCH_HELP.items():
        parser.add_argument(
            "--" + switch.replace("_", "-"),
            choices=["on", "off"],
            default=None,
            help=help_text + "; default: as the team's deploy_filter says",
        )
    parser.add_argument(
        "--visit-deadline",
        type=visit_deadline_option,
        default=None,
        metavar="D|auto|off",
        help="the filter's rule 12 on a trained DCBF team: each agent stands on every target of its "
        "territory, and on those no territory holds that it sweeps, at least every D steps; auto: "
        "the territory rule's worst max_neglect on 10 calibration episodes (the lower of the split's "
        "and the team's planned groups'); default: as the team's "
        "deploy_filter says",
    )


def visit_deadline_option(text: str) -> int | str:
    """``--visit-deadline``'s value: a whole number of steps, ``off`` or ``auto``."""
    word = text.strip().lower()
    if word in (BOUND_OFF, BOUND_AUTO):
        return word
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a whole number of steps, 'off' or 'auto', got {text!r}"
        ) from None


def apply_switches(
    team: Any, args: argparse.Namespace, graph: Any = None, env_kwargs: dict[str, Any] | None = None
) -> None:
    """Every filter switch flag of ``args`` (:func:`add_switch_options`) on ``team``, and
    ``--visit-deadline`` (``auto``: calibrated on ``graph`` with ``env_kwargs``, the team's
    settings without failures)."""
    for switch in _SWITCH_HELP:
        apply_switch(team, switch, getattr(args, switch))
    deadline = getattr(args, "visit_deadline", None)
    if deadline is None:
        return
    require_filter(team, "--visit-deadline")
    if deadline == BOUND_AUTO:
        from sb3_pm.baselines.rule_neglect import CALIBRATION_EPISODES, calibration_rules, site_deadline

        deadline = site_deadline(graph, args.agents, env_kwargs, max_cycles=args.steps)
        names = [rule.name for rule in calibration_rules(env_kwargs)]
        worst = (
            f"the lower worst max_neglect of {' and '.join(names)}"
            if len(names) > 1
            else f"{names[0]}'s worst max_neglect"
        )
        source = f"{worst} over {CALIBRATION_EPISODES} calibration episodes"
        if deadline is None:
            deadline = BOUND_OFF
            print(f"no visit deadline: {source} was the whole episode", file=sys.stderr)
        else:
            print(f"visit deadline {deadline} steps: {source}", file=sys.stderr)
        args.visit_deadline = deadline
    team.set_filter(visit_deadline=None if deadline == BOUND_OFF else deadline)


def switch_notices(team: Any, args: argparse.Namespace) -> list[str]:
    """One line per filter switch the team acts under by its own deploy_filter (not by a flag)."""
    record = team.acting_record(True)
    notices = [
        f"the team acts under the filter's {notice}"
        for switch, notice in _SWITCH_NOTICES.items()
        if getattr(args, switch) is None and record.get(switch)
    ]
    deadline = team.filter_settings.get("visit_deadline") if team.learned else None
    if getattr(args, "visit_deadline", None) is None and deadline is not None:
        source = " (calibrated on the territory rule for this site)" if deadline == BOUND_AUTO else ""
        notices.append(
            f"the team acts under the filter's rule 12, visit_deadline {deadline}{source}: each agent "
            "stands on every target of its territory and sweep at least that often (--visit-deadline off "
            "to act without it)"
        )
    return notices


def apply_temperature(team: Any, temperature: float | None, stochastic: bool = False) -> None:
    """``--temperature``: the sampling temperature of a trained DCBF team; a baseline has none.
    ``--stochastic`` samples from the trained distribution (temperature 1), also on a team whose
    config set another ``deploy_temperature``."""
    from sb3_pm.errors import UsageError

    if stochastic and team.deploy_temperature is not None:
        temperature = 1.0
    if temperature is None:
        return
    if not team.learned:
        raise UsageError(f"--temperature needs a trained team; {team.name!r} is not one")
    team.set_sampling_temperature(temperature)


def acting_rule(args: argparse.Namespace) -> bool | None:
    """``deterministic`` for the harness from ``--deterministic`` / ``--stochastic`` /
    ``--temperature``, or ``None``: the team's own ``deploy_temperature`` decides."""
    if args.deterministic:
        return True
    if args.stochastic or args.temperature is not None:
        return False
    return None


__all__ = [
    "BOUND_AUTO",
    "BOUND_OFF",
    "acting_rule",
    "add_switch_options",
    "apply_neglect_bound",
    "apply_switch",
    "apply_switches",
    "visit_deadline_option",
    "apply_temperature",
    "neglect_bound_option",
    "require_filter",
    "resolve_auto_bound",
    "switch_notices",
]
