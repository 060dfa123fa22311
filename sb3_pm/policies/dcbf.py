"""The discrete control-barrier-function (DCBF) safety filter (paper §III.E).

See docs/METHOD.md, "DCBF safety filter".

The filter turns the predicted next-step uncertainties ``û`` and the agent's own mental map into a
boolean mask over destination nodes; the actor's categorical distribution is then restricted to
that mask (sb3-contrib's masked categorical). It is vectorized over a batch and has no learnable
parameters. Rules, in order (``R`` = reachable set, ``φ`` = own node):

1. feasibility: only ``R``;
2. ``h = (1 - η) · max_m û_m`` over *all* nodes;
3. safe set ``S = {m ∈ R : û_m ≥ h}``;
4. if ``S`` is empty: the nodes of ``R`` with the largest ``û`` (ties kept, so sampling breaks them
   at random);
5. freeze: ``S = {φ}`` while the agent stands on a known target, has stayed there fewer than
   ``freeze_steps`` steps (``dwell``, 0 on arrival) and observes ``u > 0`` there; it ends early
   once it observes ``u = 0``. Because ``dwell`` restarts at 0 on arrival, a freeze starts on every
   arrival at a target, including the agent's start node;
6. ``avoid_collisions``: drop from ``S`` the nodes observed *this step* (``age == 0``) to hold
   another agent, unless that empties ``S``;
7. activation threshold ``γ``: rules 2-6 apply only where ``max_m û_m ≥ γ``; elsewhere the mask is
   ``R`` (default ``γ = 0``: always, as in the paper's experiments);
8. ``neglect_bound`` ``B`` (not in the paper; off by default in the paper-faithful config): where
   a known target is *due* (its worst-case uncertainty on arrival could otherwise exceed ``B``),
   the mask is the next hops towards it, whatever rules 2-7 said; rule 6 still applies within
   those hops. See :mod:`sb3_pm.policies.neglect_bound` for the rule and its guarantee;
9. ``leave_cleared`` (not in the paper; off unless set): on a known target the agent observes at
   ``u = 0``, its own node is dropped from ``S`` after rule 6, unless that empties ``S``. Staying
   there lowers no uncertainty, while every other target's keeps growing; it is what a learner
   that has settled on one target of its group does. Gated by rule 7 like rules 2-6; rule 8
   overrides it;
10. ``pass_held`` (not in the paper; off unless set; needs the env's ``advice_input``, whose column
    is the map's last): an agent off targets whose advised next node (the territory rule's move)
    is observed this step to hold another agent stays while ``dwell`` is 0; once it has stayed a
    step (``dwell >= 1``, any step on the node), if that node is still held, the mask is that node
    alone (its own node if the advised one is not reachable). It overrides rules 2-6 and 9 (rule 6 would
    turn the agent away from the held node for good: on a tree a teammate on the only path
    locks it out, research/LOG.md); rule 7 gates it and rule 8 overrides it;
11. ``keep_moving`` (not in the paper; off unless set; needs ``advice_input`` as rule 10 does): an
    agent off targets whose advised next node is another node, not observed held, does not stay:
    its own node is dropped from ``S`` after rule 10, unless that empties ``S``. A learner can
    idle on a node it rarely met in training (a leaf of a tree) for a whole episode while the
    rule says to move on (research/LOG.md). Gated by rule 7; rule 8 overrides it;
12. ``visit_deadline`` ``D`` (not in the paper; deployment only, off unless set): the agent stands
    on each target of its visit set at least once every ``D`` steps. The set is its territory and
    the targets that no territory holds which the convention hands it to sweep; the projection is
    the agent's own memory of its visits (:mod:`sb3_pm.policies.visit_deadline`), which the
    deployed team keeps. Where a target is due, the mask is the next hops towards it, as rule 8's;
    it overrides rules 2-7 and 9-11 and yields to rule 8. On a target it only sweeps the agent is
    not frozen, and its own node is dropped from ``S`` after rule 9: the visit is made.

``barrier=False`` skips rules 2-4 (``S = R``) and keeps the freeze and rule 6: the actor chooses
among all reachable nodes but still dwells on a target until it is cleared. This is not in the
paper; it exists because rules 2-4 leave a single allowed action on almost every step (measured in
research/LOG.md), so the learned actor barely acts.

Decisions where the paper is silent: γ gates the whole filter including the freeze (the freeze is
rule 5 of the filter); rule 6 also applies to the frozen ``{φ}`` but can never empty it. A final
guard makes every row non-empty even for malformed input (falls back to ``R``, then to all nodes).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import torch as th

from sb3_pm.envs.mental_map import AGE, FEATURES, OCCUPIED, TARGET, U
from sb3_pm.errors import InputError
from sb3_pm.policies.edges import is_edge_layout
from sb3_pm.policies.neglect_bound import neglect_deadline
from sb3_pm.policies.visit_deadline import SWEPT, VISIT_AGE, VISIT_TARGETS, check_visit_deadline, visit_hops

NEGLECT_SCOPES = ("known", "unserved", "territory")
#: The filter's on/off rules a deployment may switch: rules 9, 10 and 11.
FILTER_SWITCHES = ("leave_cleared", "pass_held", "keep_moving")
#: The switches that read the env's advice column (``advice_input``).
ADVICE_SWITCHES = ("pass_held", "keep_moving")


@dataclass(frozen=True)
class DCBFConfig:
    """Settings of the filter.

    :param eta: the margin ``η`` of rule 2, in ``[0, 1]``.
    :param freeze_steps: length of the freeze of rule 5 (0 disables it).
    :param avoid_collisions: apply rule 6.
    :param gamma_threshold: the activation threshold ``γ`` of rule 7, in units of ``u``.
    :param barrier: apply rules 2-4 (off: ``S = R`` before the freeze and rule 6).
    :param neglect_bound: rule 8's bound ``B`` in units of ``u`` (``None``: rule 8 off).
    :param neglect_scope: the targets rule 8 bounds: ``"known"`` (every target in the map),
        ``"unserved"`` (those last observed with no other agent on them: a target last seen held
        by a teammate is left to that teammate) or ``"territory"`` (the targets of the agent's own
        territory, :attr:`territory`, whether or not its map has seen them yet).
    :param territory: with ``neglect_scope="territory"``, the agent's own targets (node indices):
        its share of the site's targets under the split of :mod:`sb3_pm.graphs.territories`.
    :param leave_cleared: apply rule 9 (an agent on a target it observes cleared does not stay).
    :param pass_held: apply rule 10 (an agent whose advised node is held waits a step, then passes).
    :param keep_moving: apply rule 11 (an agent off targets advised to a free node does not stay).
    :param visit_deadline: rule 12's deadline ``D`` in steps (``None``: rule 12 off); deployment
        only, since it reads the team's memory of its visits.
    """

    eta: float = 0.1
    freeze_steps: int = 10
    avoid_collisions: bool = False
    gamma_threshold: float = 0.0
    barrier: bool = True
    neglect_bound: float | None = None
    neglect_scope: str = "known"
    territory: tuple[int, ...] = ()
    leave_cleared: bool = False
    pass_held: bool = False
    keep_moving: bool = False
    visit_deadline: int | None = None

    def __post_init__(self) -> None:
        if not 0.0 <= self.eta <= 1.0:
            raise InputError(f"eta must be in [0, 1], got {self.eta}")
        if self.freeze_steps < 0:
            raise InputError(f"freeze_steps must be >= 0, got {self.freeze_steps}")
        if self.neglect_bound is not None and not self.neglect_bound >= 1:
            raise InputError(
                f"neglect_bound must be at least 1 (or null to turn it off), got {self.neglect_bound}"
            )
        if self.neglect_scope not in NEGLECT_SCOPES:
            raise InputError(f"neglect_scope must be one of {NEGLECT_SCOPES}, got {self.neglect_scope!r}")
        if any(isinstance(node, bool) or not isinstance(node, int) or node < 0 for node in self.territory):
            raise InputError(f"territory must list node indices (ints >= 0), got {self.territory!r}")
        for switch in FILTER_SWITCHES:
            if not isinstance(getattr(self, switch), bool):
                raise InputError(f"{switch} must be true or false, got {getattr(self, switch)!r}")
        if self.visit_deadline is not None:
            check_visit_deadline(self.visit_deadline)


def check_bound_below_cap(bound: float | None, u_max: float) -> None:
    """Refuse a neglect bound above the uncertainty cap: rule 8 projects at most ``u_max``, so such
    a bound would hold without the filter doing anything and would (almost) never bind.

    :raises InputError: naming both values.
    """
    if bound is not None and bound > u_max:
        raise InputError(
            f"neglect_bound {bound:g} is above the environment's u_max {u_max:g}: no target's "
            "uncertainty can exceed u_max, so the bound would never bind; choose B <= u_max"
        )


#: The DCBF settings a trained team may switch on for deployment (a config's ``deploy_filter``).
DEPLOY_FILTER_KEYS = ("neglect_bound", "neglect_scope", *FILTER_SWITCHES, "visit_deadline")
#: ``deploy_filter: {neglect_bound: auto}``: a territory bound measured on each site the team is
#: deployed on, before it acts there (:mod:`sb3_pm.evaluation.neglect_calibration`).
SITE_BOUND = "auto"


def check_deploy_filter(value: object) -> dict[str, object] | None:
    """A team's deployment filter: ``None`` (act with the filter it trained under) or a mapping
    ``{neglect_bound: B, neglect_scope: known | unserved | territory, leave_cleared: bool,
    pass_held: bool, keep_moving: bool, visit_deadline: D}``.

    The scope is optional (``known`` by default), checked as :class:`DCBFConfig` checks it;
    ``neglect_bound: auto`` is a territory bound calibrated on each deployment site (scope
    ``territory``, the only one it takes). The switches ``leave_cleared`` (rule 9) and
    ``pass_held`` (rule 10), ``keep_moving`` (rule 11) and the deadline ``visit_deadline`` (rule
    12, in steps) are optional and kept only where given; with one of them on the bound may be left
    out (``neglect_bound: null``: those alone).

    :raises InputError: anything else, naming the problem.
    """
    if value is None:
        return None
    if not isinstance(value, dict):
        raise InputError(f"expected null or a mapping {{neglect_bound: B, neglect_scope: S}}, got {value!r}")
    unknown = sorted(set(value) - set(DEPLOY_FILTER_KEYS))
    if unknown:
        raise InputError(f"unknown key {unknown[0]!r} (known: {', '.join(DEPLOY_FILTER_KEYS)})")
    switches: dict[str, object] = {}
    for switch in FILTER_SWITCHES:
        if switch in value:
            if not isinstance(value[switch], bool):
                raise InputError(f"{switch} must be true or false, got {value[switch]!r}")
            switches[switch] = value[switch]
    deadline = value.get("visit_deadline")
    if deadline is not None:  # rule 12, kept where given, as the switches; auto: per site
        switches["visit_deadline"] = SITE_BOUND if deadline == SITE_BOUND else check_visit_deadline(deadline)
    bound = value.get("neglect_bound")
    if bound is None and switches:
        # the checked form's scope is known (what a saved team's manifest holds): any other needs a bound
        if value.get("neglect_scope", "known") != "known":
            scope = value["neglect_scope"]
            raise InputError(f"neglect_scope {scope!r} needs a neglect_bound (a number or auto)")
        if not any(switches.values()):
            named = ", ".join(switches)
            raise InputError(f"a deploy_filter of {named}: false alone changes nothing; use null")
        return {"neglect_bound": None, "neglect_scope": "known", **switches}
    if bound == SITE_BOUND:
        scope = value.get("neglect_scope", "territory")
        if scope != "territory":
            raise InputError(
                f"neglect_bound auto is a territory bound (calibrated on each agent's territory); "
                f"neglect_scope {scope!r} cannot go with it"
            )
        return {"neglect_bound": SITE_BOUND, "neglect_scope": "territory", **switches}
    if bound is None or isinstance(bound, bool) or not isinstance(bound, (int, float)):
        raise InputError(
            f"neglect_bound must be a number (the bound B) or auto (or left out, with a switch on), "
            f"got {bound!r}"
        )
    if not math.isfinite(bound):
        raise InputError(f"neglect_bound must be finite, got {bound!r}")
    scope = value.get("neglect_scope", "known")
    DCBFConfig(neglect_bound=float(bound), neglect_scope=scope)  # the filter's own checks
    return {"neglect_bound": float(bound), "neglect_scope": scope, **switches}


def territory_mask(territory: tuple[int, ...], batch: int, n_nodes: int, device: th.device) -> th.Tensor:
    """``(batch, n_nodes)`` bool, True on the territory's nodes (rule 8's scope ``"territory"``): a
    read-only view of one cached ``(n_nodes,)`` row, since the filter runs at every step."""
    if territory and max(territory) >= n_nodes:
        raise InputError(
            f"the neglect bound's territory names node {max(territory)}, but the graph has {n_nodes} nodes"
        )
    return _territory_row(territory, n_nodes, device).expand(batch, n_nodes)


@functools.lru_cache(maxsize=64)
def _territory_row(territory: tuple[int, ...], n_nodes: int, device: th.device) -> th.Tensor:
    """``(n_nodes,)`` bool, True on the territory's nodes (a handful of learners and graphs per run)."""
    row = th.zeros(n_nodes, dtype=th.bool, device=device)
    row[list(territory)] = True
    return row


def _non_empty(mask: th.Tensor, fallback: th.Tensor) -> th.Tensor:
    """``mask`` where its row has a True entry, else ``fallback`` (rows of ``(B, N)`` bool)."""
    return th.where(mask.any(-1, keepdim=True), mask, fallback)


def dcbf_mask(
    u_hat: th.Tensor,
    reachable: th.Tensor,
    position: th.Tensor,
    on_target: th.Tensor,
    u_here: th.Tensor,
    dwell: th.Tensor,
    occupied_now: th.Tensor,
    config: DCBFConfig = DCBFConfig(),
    deadline: tuple[th.Tensor, th.Tensor] | None = None,
    advice: th.Tensor | None = None,
    visit: tuple[th.Tensor, th.Tensor] | None = None,
    sweeping: th.Tensor | None = None,
) -> th.Tensor:
    """Apply rules 1-12 to a batch.

    :param u_hat: predicted (or last observed) uncertainty per node.
    :param reachable: the reachable set ``R`` (bool).
    :param position: the agent's node ``φ`` (long).
    :param on_target: the agent's node is a known target (bool).
    :param u_here: the uncertainty the agent observes at its node now.
    :param dwell: steps the agent has stayed on its node (0 on arrival).
    :param occupied_now: nodes observed this step to hold another agent (bool).
    :param config: the filter's settings.
    :param deadline: rule 8's ``(forced, next_hops)`` from
        :func:`~sb3_pm.policies.neglect_bound.neglect_deadline` (``None``: rule 8 off).
    :param advice: the advised next node, one-hot (bool); read by rules 10 and 11 only, which need it.
    :param visit: rule 12's ``(forced, next_hops)`` from
        :func:`~sb3_pm.policies.visit_deadline.visit_hops` (``None``: rule 12 off).
    :param sweeping: rule 12: the agent stands on a target it only sweeps (bool); it is not frozen
        there and its own node is dropped from ``S`` after rule 9, unless that empties ``S``.
    :return: the mask ``S`` (bool), never all-false.

    Shapes:
        - u_hat, reachable, occupied_now: ``(B, N)``
        - position, on_target, u_here, dwell: ``(B,)``
        - deadline: ``(B,)`` bool, ``(B, N)`` bool
        - advice: ``(B, N)`` bool
        - visit: ``(B,)`` bool, ``(B, N)`` bool; sweeping: ``(B,)`` bool
        - output: ``(B, N)`` bool
    """
    reachable = reachable.bool()
    very_low = th.finfo(u_hat.dtype).min
    u_max_all = u_hat.amax(-1, keepdim=True)  # (B, 1), rule 2 is over all nodes
    h = (1.0 - config.eta) * u_max_all
    safe = reachable & (u_hat >= h)  # rule 3
    # Rule 4: best reachable nodes, ties kept.
    u_reachable = u_hat.masked_fill(~reachable, very_low)
    best = reachable & (u_reachable >= u_reachable.amax(-1, keepdim=True))
    safe = _non_empty(safe, best) if config.barrier else reachable
    # Rule 5: freeze on a target until dwell reaches freeze_steps or u is observed at 0.
    own = th.nn.functional.one_hot(position.long(), u_hat.shape[-1]).bool()
    frozen = on_target.bool() & (dwell < config.freeze_steps) & (u_here > 0)
    if sweeping is not None:  # rule 12: a target the agent only sweeps does not hold it
        frozen = frozen & ~sweeping.bool()
    safe = th.where(frozen[:, None], own, safe)
    if config.avoid_collisions:  # rule 6
        safe = _non_empty(safe & ~occupied_now.bool(), safe)
    if config.leave_cleared:  # rule 9: not on a target observed cleared (frozen needs u > 0)
        cleared = on_target.bool() & (u_here <= 0)
        safe = th.where(cleared[:, None], _non_empty(safe & ~own, safe), safe)
    if sweeping is not None:  # rule 12: the visit is made; back to its own targets
        safe = th.where(sweeping.bool()[:, None], _non_empty(safe & ~own, safe), safe)
    if config.pass_held or config.keep_moving:  # rules 10 and 11 read the advised node
        if advice is None:
            raise InputError(
                "the filter's pass_held and keep_moving (rules 10, 11) need the advised node: "
                "env_kwargs advice_input"
            )
        advice = advice.bool()
        advised_elsewhere = advice.any(-1) & ~(advice & own).any(-1)
        held_ahead = (advice & occupied_now.bool()).any(-1)
        off_target = ~on_target.bool()
        if config.pass_held:  # rule 10: wait a step for a held advised node, then take it
            blocked = off_target & advised_elsewhere & held_ahead
            waited = dwell >= 1
            choice = th.where(waited[:, None], _non_empty(advice & reachable, own), own)
            safe = th.where(blocked[:, None], choice, safe)
        if config.keep_moving:  # rule 11: off targets, advised on to a free node: do not stay
            idle = off_target & advised_elsewhere & ~held_ahead
            safe = th.where(idle[:, None], _non_empty(safe & ~own, safe), safe)
    # Rule 7: the filter is active only where max û >= γ.
    active = u_max_all >= config.gamma_threshold
    mask = th.where(active, safe, reachable)
    # Rule 12 first, so that rule 8, applied after it, overrides it; both override rules 2-11, and
    # rule 6 may thin, never empty, their hops.
    for rule in (visit, deadline):
        if rule is not None:
            forced, hops = rule
            hops = hops & reachable
            if config.avoid_collisions:
                hops = _non_empty(hops & ~occupied_now.bool(), hops)
            mask = th.where((forced & hops.any(-1)).unsqueeze(-1), hops, mask)
    return _non_empty(_non_empty(mask, reachable), th.ones_like(mask))


def dcbf_mask_from_map(
    observations: dict[str, th.Tensor],
    u_hat: th.Tensor,
    config: DCBFConfig = DCBFConfig(),
    u_max: float = float("inf"),
) -> th.Tensor:
    """:func:`dcbf_mask` on SB3-preprocessed mental-map observations (see :func:`dcbf_filter_from_map`)."""
    return dcbf_filter_from_map(observations, u_hat, config, u_max)[0]


def dcbf_filter_from_map(
    observations: dict[str, th.Tensor],
    u_hat: th.Tensor,
    config: DCBFConfig = DCBFConfig(),
    u_max: float = float("inf"),
) -> tuple[th.Tensor, th.Tensor]:
    """:func:`dcbf_mask` on SB3-preprocessed mental-map observations, and where rule 8 forced it.

    ``position`` arrives one-hot (SB3 preprocessing of ``Discrete``) and node features are raw
    (unnormalized), as the env emits them. ``u_max`` caps rule 8's worst-case projection.

    Shapes:
        - observations: ``nodes`` ``(B, N, 5)``, ``adjacency`` ``(B, N, N)``, ``position``
          ``(B, N)``, ``dwell`` ``(B, 1)``, ``action_mask`` ``(B, N)``, optionally
          ``neglect_territory`` ``(B, N)`` bool (each map's territory, in place of
          ``config.territory``), and with rule 12 ``visit_targets`` ``(B, N)`` bool and
          ``visit_age`` ``(B, N)`` float (the team's memory, :mod:`sb3_pm.policies.visit_deadline`);
          u_hat: ``(B, N)``
        - output: the mask ``(B, N)`` bool and ``forced`` ``(B,)`` bool (rule 8 chose the mask;
          all false when rule 8 is off)
    """
    nodes = observations["nodes"]
    # The policy passes the index along; a caller with only the one-hot gets it by argmax.
    position = observations.get("position_index")
    if position is None:
        position = observations["position"].argmax(-1)
    rows = th.arange(nodes.shape[0], device=nodes.device)
    here = nodes[rows, position]  # (B, 5): the own node's features
    reachable = observations["action_mask"] > 0.5
    # rules 8 and 12 search the edges layout's known edges as they are, never as (B, N, N)
    known_edges = (
        (observations["edge_index"], observations["edge_mask"])
        if is_edge_layout(observations)
        else observations.get("adjacency")
    )
    deadline = None
    if config.neglect_bound is not None:
        if config.neglect_scope == "territory":
            # Several learners' maps filtered in one call carry each map's own territory.
            bounded = observations.get("neglect_territory")
            if bounded is None:
                bounded = territory_mask(config.territory, nodes.shape[0], nodes.shape[1], nodes.device)
        else:
            bounded = nodes[..., TARGET] > 0.5
        if config.neglect_scope == "unserved":
            bounded = bounded & ~(nodes[..., OCCUPIED] > 0.5)
        deadline = neglect_deadline(
            nodes[..., U],
            nodes[..., AGE],
            bounded,
            known_edges,
            position,
            reachable,
            config.neglect_bound,
            u_max,
        )
    visit = sweeping = None
    if config.visit_deadline is not None:
        if VISIT_TARGETS not in observations or VISIT_AGE not in observations:
            raise InputError(
                "the filter's visit_deadline (rule 12) reads the team's memory of its visits: deploy "
                "the team (team.predict, evaluate()), not a bare policy"
            )
        visit = visit_hops(
            nodes[..., U],
            nodes[..., AGE],
            observations[VISIT_AGE],
            observations[VISIT_TARGETS],
            known_edges,
            position,
            reachable,
            config.visit_deadline,
            u_max,
        )
        sweeping = observations[VISIT_TARGETS][rows, position] == SWEPT
    mask = dcbf_mask(
        u_hat,
        reachable,
        position,
        here[:, TARGET] > 0.5,
        here[:, U],
        observations["dwell"].reshape(-1),
        (nodes[..., OCCUPIED] > 0.5) & (nodes[..., AGE] == 0),
        config,
        deadline,
        # the env's advice column is the map's last (sb3_pm.envs.mental_map); rules 10, 11 read it
        nodes[..., -1] > 0.5
        if (config.pass_held or config.keep_moving) and nodes.shape[-1] > len(FEATURES)
        else None,
        visit,
        sweeping,
    )
    forced = deadline[0] if deadline is not None else th.zeros_like(rows, dtype=th.bool)
    return mask, forced
