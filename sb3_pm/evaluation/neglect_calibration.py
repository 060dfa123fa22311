"""A neglect bound for a new site, calibrated on the territory rule: ``--neglect-bound auto``.

The DCBF's neglect bound (rule 8, scope ``territory``) makes each agent keep the known targets of
its own territory below ``B``. Its guarantee holds for one due target at a time, so a bound the
territories cannot keep forces move after move and costs more than it saves: on the held-out
graphs where every policy lets some target reach ``u_max`` (research/LOG.md 3h, "Transfer"), a
fixed ``B`` forced a third to two thirds of all moves. How tight a bound a site allows is a
property of the site and the split, not of a learned team, so it can be measured before
deployment by the rule that follows the same split, ``territory_patrol``
(:mod:`sb3_pm.baselines.territory_patrol`):

* run ``territory_patrol`` for ``episodes`` calibration episodes on the site, with the team's
  size (whose split the bound follows) and the deployment's environment settings, from seeds of
  its own (apart from the sweeps' evaluation seeds);
* ``P`` = the largest ``peak_uncertainty`` of those episodes: the worst uncertainty the territory
  rule let any target reach;
* if ``P`` reaches ``u_max`` the territories cannot be held and no bound is deployed (``None``);
  otherwise ``B = max(1, ceil(margin · P))``, at most ``u_max``.

``margin`` = 1, the bound at the rule's own worst peak, is the best of the margins measured with
the transferable team (the measurements: research/LOG.md §3h, "Transfer", "The calibration
margin"). A margin below 1 is refused: it would ask for a bound the territory rule itself did not
keep. The rule needs the site's road network and target list, which a team with a known map has
anyway; it reads no learned team.

Rule 8's guarantee assumes targets start at ``u = 0`` (a target the map has not seen projects as
its age), so a site with ``initial_uncertainty: random`` is refused rather than calibrated.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

from sb3_pm.baselines.rule_neglect import CALIBRATION_EPISODES, CALIBRATION_SEED, NOT_CALIBRATED, rule_worst
from sb3_pm.envs.core import DEFAULT_U_MAX
from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphLike, resolve_graph

#: ``B = ceil(MARGIN · P)``: the territory rule's worst peak itself (module docstring).
MARGIN = 1.0
# CALIBRATION_EPISODES and CALIBRATION_SEED: the territory rule's calibration episodes, shared
# with the filter's rule 12 (sb3_pm.baselines.rule_neglect), apart from the sweeps' seeds.


@dataclass(frozen=True)
class CalibratedBound:
    """What :func:`calibrate_neglect_bound` found.

    :ivar bound: ``B``, or ``None`` when the territory rule let a target reach ``u_max``.
    :ivar peak: ``P``, the territory rule's worst ``peak_uncertainty`` over the episodes.
    :ivar u_max: the environment's cap.
    :ivar episodes: calibration episodes run; ``seed`` the env seed of the first.
    :ivar n_agents: the team size (and split) calibrated for; ``max_cycles`` the episode length.
    """

    bound: float | None
    peak: float
    u_max: float
    episodes: int
    seed: int
    margin: float
    n_agents: int
    max_cycles: int

    @property
    def capped(self) -> bool:
        """Whether ``B`` is ``u_max`` because ``ceil(margin · P)`` is above it."""
        return self.bound is not None and self.bound < math.ceil(self.margin * self.peak)

    def to_dict(self) -> dict[str, Any]:
        """The fields, JSON-ready, under ``rule: auto``."""
        return {"rule": "auto", **asdict(self)}

    def describe(self) -> str:
        """One line for the user: the bound and where it came from."""
        source = f"territory_patrol's worst peak over {self.episodes} calibration episodes was {self.peak:g}"
        if self.bound is None:
            return f"no neglect bound: {source}, at u_max {self.u_max:g}, so the territories cannot be held"
        cap = f", capped at u_max {self.u_max:g}" if self.capped else ""
        return f"neglect bound {self.bound:g} on each agent's territory: {source}, x {self.margin:g}{cap}"


def calibrate_neglect_bound(
    graph: GraphLike,
    n_agents: int,
    env_kwargs: Mapping[str, Any] | None = None,
    max_cycles: int = 500,
    episodes: int = CALIBRATION_EPISODES,
    seed: int = CALIBRATION_SEED,
    margin: float = MARGIN,
) -> CalibratedBound:
    """The territory bound a site allows (module docstring): ``B = ceil(margin · P)`` or none.

    :param graph: the deployment site (a preset name, a ``.graphml`` path or a ``GraphSpec``).
    :param n_agents: the team size whose territories the bound follows (the split, and so the
        rule, depends on it).
    :param env_kwargs: the deployment's environment settings (``u_max`` among them); failures are
        not calibrated for: pass the settings without them.
    :raises InputError: for ``episodes < 1``, ``margin < 1`` or ``initial_uncertainty: random``.
    """
    if episodes < 1:
        raise InputError(f"calibration episodes must be at least 1, got {episodes}")
    if not math.isfinite(margin) or margin < 1:
        raise InputError(
            f"the calibration margin must be at least 1 (B at or above the rule's peak), got {margin}"
        )
    spec = resolve_graph(graph)
    kwargs = dict(env_kwargs or {})
    if kwargs.get("initial_uncertainty", "zero") != "zero":
        raise InputError(
            "a neglect bound cannot be calibrated with initial_uncertainty "
            f"{kwargs['initial_uncertainty']!r}: rule 8's guarantee assumes targets start at u = 0"
        )
    u_max = int(kwargs.get("u_max", DEFAULT_U_MAX))
    # the episodes evaluate() would play; a peak at u_max ends them (no bound can follow)
    peak = rule_worst("peak_uncertainty", spec, n_agents, kwargs, max_cycles, episodes, seed, ceiling=u_max)
    bound = None if peak >= u_max else float(min(u_max, max(1, math.ceil(margin * peak))))
    return CalibratedBound(
        bound=bound,
        peak=peak,
        u_max=float(u_max),
        episodes=episodes,
        seed=seed,
        margin=margin,
        n_agents=n_agents,
        max_cycles=max_cycles,
    )


def settle_site_bound(
    team: Any, graph: GraphLike, n_agents: int, env_kwargs: Mapping[str, Any], max_cycles: int
) -> CalibratedBound:
    """Give a team whose ``deploy_filter`` is ``{neglect_bound: auto}`` its bound on ``graph``.

    Calibrates (:func:`calibrate_neglect_bound`) with the team's size and the deployment's env
    settings (agent failures left out) and sets the result on the team's territories, or no bound
    where the territories cannot be held; the team's ``site_bound_pending`` is then settled.

    :raises InputError: ``n_agents`` other than the team's size (the bound keeps the trained split,
        and agents sharing a learner would share a territory), or a site that cannot be calibrated.
    """
    way_out = (
        "or set the filter first (team.set_filter(neglect_bound=B or None); "
        "sb3-pm evaluate --neglect-bound B or off)"
    )
    trained = int(team.n_agents)
    if n_agents != trained:
        raise InputError(
            f"the team's deploy_filter auto calibrates its {trained} agents' territories, and "
            f"{n_agents} agents were asked for: deploy it with {trained}, {way_out}"
        )
    kwargs = {key: value for key, value in env_kwargs.items() if key not in NOT_CALIBRATED}
    try:
        calibration = calibrate_neglect_bound(graph, n_agents, kwargs, max_cycles=max_cycles)
    except InputError as error:
        raise InputError(f"neglect bound auto: {error}; {way_out}") from None
    if calibration.bound is None:
        team.set_filter(neglect_bound=None)
    else:
        team.set_filter(neglect_bound=calibration.bound, neglect_scope="territory")
    return calibration


def unsettle_site_bound(team: Any) -> None:
    """Undo :func:`settle_site_bound` (the deployment it was for failed): no bound, and a site
    still to calibrate."""
    team.await_site_bound()


__all__ = [
    "CALIBRATION_EPISODES",
    "CALIBRATION_SEED",
    "MARGIN",
    "CalibratedBound",
    "calibrate_neglect_bound",
    "settle_site_bound",
    "unsettle_site_bound",
]
