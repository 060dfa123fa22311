"""The visit deadline (the filter's rule 12): every target of an agent's visit set is stood on at
least once every ``D`` steps.

Rule 8 (:mod:`sb3_pm.policies.neglect_bound`) bounds a target's uncertainty, which the cap
``u_max`` stops: it cannot ask that a target be visited within more than ``u_max`` steps. On a
site where the best patrol leaves some targets waiting longer than that, and on targets that a
planned convention gives to nobody, a team can then leave a target unvisited for a whole episode.
Rule 12 bounds the run itself: ``max_neglect`` (the longest stretch of steps with no agent on a
target) in steps.

Each agent's *visit set* is its territory and the targets no territory holds that the convention
hands it to sweep (:func:`sb3_pm.planning.conventions.sweep_targets`). For each target ``m`` of it
the agent projects the length of the target's current run from what it knows alone:

    ``n_m = min(since_m, u_m + age_m)``, the second term only where ``u_m < u_max``

``since_m`` is the agent's own memory: the steps since it last stood on ``m`` (since the episode
began, if never). A teammate's visit only shortens the true run, so ``since_m`` bounds it. The
map's ``u_m`` last observed ``age_m`` steps ago bounds it too, as long as it was below the cap:
eq. (1) raises an unvisited target's ``u`` by exactly one per step, so a run of ``r`` steps leaves
``u >= min(r, u_max)``. With ``d_m`` the agent's hop distance to ``m`` over its known edges, ``m``
is *due* when ``n_m + d_m >= D``, and the mask is then the next hops along shortest known paths
to the nearest due target: rule 8's walk
(:func:`~sb3_pm.policies.neglect_bound.neglect_deadline`), on this projection and with no cap. On
a target it only sweeps the agent is not held: one step resets the run, and the plan left that
target to nobody.

**Guarantee**, by rule 8's argument: with a static graph and known edges, a target of the agent's
visit set waits at most ``D`` steps between visits as long as no other target of the set is due
while it is due. A walk begun now ends the target's true run ``r_m <= n_m`` at ``r_m + d_m - 1``
steps; one step raises ``r_m + d_m`` by at most 2, so it is at most ``D + 1`` when the target falls
due, and each step of the walk keeps it so. The bound counts from the first visit: a target more
than ``D + 1`` hops from the agent's start waits the walk there. When two are due together one of
them can wait longer. The target underfoot (``n = d = 0``) is never due, so ``D = 1`` sends an
agent back and forth between two adjacent targets. The memory lives in the deployed team
(:class:`~sb3_pm.agents.deployment.visit_memory.VisitMemory`), one row per agent, so the rule is
for deployment: a policy filtered without it refuses to act.
"""

from __future__ import annotations

import torch as th

from sb3_pm.errors import InputError
from sb3_pm.policies.neglect_bound import EdgeMaps, neglect_deadline

#: The observation keys the deployed team adds for rule 12: each map's visit set ``(B, N)`` (0 off
#: it, 1 on the agent's territory, :data:`SWEPT` on a target it sweeps) and its memory ``since``
#: ``(B, N)`` float.
VISIT_TARGETS = "visit_targets"
VISIT_AGE = "visit_age"
#: The value of ``visit_targets`` on a target the agent sweeps (1 on its territory's): one step
#: there resets the target's run, so the agent is not held there (the freeze does not apply).
SWEPT = 2
#: A projection above any deadline (a target last observed at the cap, never remembered).
_UNKNOWN = float(1 << 30)


def check_visit_deadline(deadline: object) -> int:
    """``deadline`` if it is a whole number of steps ``>= 1``, else a one-line :class:`InputError`."""
    if isinstance(deadline, bool) or not isinstance(deadline, int) or deadline < 1:
        raise InputError(f"visit_deadline must be a whole number of steps >= 1 (or null), got {deadline!r}")
    return deadline


def run_projection(u_last: th.Tensor, age: th.Tensor, since: th.Tensor, u_max: float) -> th.Tensor:
    """``n``: an upper bound on each target's current run of steps with no agent on it.

    Shapes:
        - u_last, age, since: ``(B, N)``
        - output: ``(B, N)`` float
    """
    seen = th.where(u_last < u_max, u_last + age, th.full_like(u_last, _UNKNOWN))
    return th.minimum(seen, since.to(u_last.dtype))


def visit_hops(
    u_last: th.Tensor,
    age: th.Tensor,
    since: th.Tensor,
    visit_targets: th.Tensor,
    adjacency: th.Tensor | EdgeMaps,
    position: th.Tensor,
    reachable: th.Tensor,
    deadline: int,
    u_max: float,
) -> tuple[th.Tensor, th.Tensor]:
    """Which maps have a due target of their visit set, and the next hops towards the nearest one.

    :param u_last: the map's last observed ``u``; ``age``: steps since each node was observed.
    :param since: the agent's steps since it last stood on each node (the team's memory).
    :param visit_targets: the agent's visit set (bool).
    :param adjacency: the known adjacency ``(B, N, N)`` or an edges-layout batch's known edges.
    :param position: the agent's node; ``reachable``: the reachable set ``R`` (bool).
    :param deadline: ``D`` in steps; ``u_max``: the cap of ``u``.
    :return: ``forced`` ``(B,)`` bool and the next hops ``(B, N)`` bool (meaningful where forced).

    Shapes:
        - u_last, age, since, visit_targets, reachable: ``(B, N)``; position: ``(B,)`` long
    """
    projected = run_projection(u_last, age, since, u_max)
    # neglect_deadline adds age to its first argument and caps it: the run needs neither. Its test
    # is arrival >= bound - 1, one step ahead for u; the run's is n + d >= D (module docstring).
    return neglect_deadline(
        projected,
        th.zeros_like(projected),
        visit_targets.bool(),
        adjacency,
        position,
        reachable,
        float(deadline) + 1.0,
        float("inf"),
    )


__all__ = ["SWEPT", "VISIT_AGE", "VISIT_TARGETS", "check_visit_deadline", "run_projection", "visit_hops"]
