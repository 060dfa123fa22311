"""One agent patrolling a group of targets with the true uncertainties (docs/PLANNING.md "Plans").

Two rules, per step: on a group target with ``u > 0``, dwell; else keep walking to the goal chosen
earlier; else choose the next goal and step along a shortest path to it:

* ``stalest`` (:func:`group_move`): the group's other target with the highest ``u`` (ties:
  nearest, then lowest node);
* ``tour`` (:func:`tour_move`): the next target of a closed tour through the group (from off the
  group: the nearest).

A group of one target is held once reached. :func:`solo_cost` runs a rule for one agent alone on
its group, which is what the plan search prices. All work on plain Python ints, because a search
prices thousands of (start, group) pairs and a few-target step is far cheaper without NumPy.
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["RULES", "dropped_cost", "group_move", "solo_cost", "tour_move"]


def _dwell_or_keep_going(
    position: int, goal: int | None, group: Sequence[int], u: Sequence[int], next_hop: Sequence[Sequence[int]]
) -> tuple[int, int | None] | None:
    """The first steps every rule shares: stay put with no group, dwell on a group target with
    ``u > 0``, keep walking to an unreached goal; ``None`` when the rule must choose a goal."""
    if not group or (position in group and u[position] > 0):
        return position, None
    if goal is not None and goal != position:
        return next_hop[position][goal], goal
    return None


def group_move(
    position: int,
    goal: int | None,
    group: Sequence[int],
    u: Sequence[int],
    distances: Sequence[Sequence[int]],
    next_hop: Sequence[Sequence[int]],
) -> tuple[int, int | None]:
    """The agent's next node by the group rule, and the goal it keeps.

    :param position: the agent's node.
    :param goal: the goal kept from the last step, or ``None``.
    :param group: the group's target nodes.
    :param u: the true uncertainty of every node (indexable by node).
    :param distances: hop distances, ``distances[a][b]``.
    :param next_hop: ``next_hop[a][b]``, the first node of a shortest path from ``a`` to ``b``.
    """
    settled = _dwell_or_keep_going(position, goal, group, u, next_hop)
    if settled is not None:
        return settled
    best: int | None = None
    best_key: tuple[int, int, int] | None = None
    for target in group:
        if target == position:
            continue
        key = (-u[target], distances[position][target], target)
        if best_key is None or key < best_key:
            best, best_key = target, key
    if best is None:  # a group of one target, reached
        return position, None
    return next_hop[position][best], best


def tour_move(
    position: int,
    goal: int | None,
    group: Sequence[int],
    u: Sequence[int],
    distances: Sequence[Sequence[int]],
    next_hop: Sequence[Sequence[int]],
) -> tuple[int, int | None]:
    """The agent's next node by the tour rule (``group`` in tour order), and the goal it keeps;
    arguments as :func:`group_move`."""
    settled = _dwell_or_keep_going(position, goal, group, u, next_hop)
    if settled is not None:
        return settled
    if position in group:
        if len(group) == 1:
            return position, None
        following = group[(list(group).index(position) + 1) % len(group)]
    else:
        following = min(group, key=lambda target: (distances[position][target], target))
    return next_hop[position][following], following


#: The group rules by name.
RULES = {"stalest": group_move, "tour": tour_move}


def solo_cost(
    start: int,
    group: Sequence[int],
    initial: Sequence[int],
    max_cycles: int,
    u_max: int,
    distances: Sequence[Sequence[int]],
    next_hop: Sequence[Sequence[int]],
    rule: str = "stalest",
) -> int:
    """The group's summed uncertainty over an episode with one agent from ``start`` on it alone.

    :param initial: the group targets' ``u`` at reset, in ``group`` order.
    :param rule: a key of :data:`RULES` (for ``tour``, ``group`` is in tour order).
    :return: ``Σ_k Σ_group u`` over steps ``k = 1 .. max_cycles``.
    """
    group = list(group)
    values = {target: int(value) for target, value in zip(group, initial)}
    move = RULES[rule]
    position, goal, total = start, None, 0
    for _ in range(max_cycles):
        position, goal = move(position, goal, group, values, distances, next_hop)
        for target in group:
            value = values[target]
            if target == position:
                values[target] = value - 1 if value > 0 else 0
            else:
                values[target] = value + 1 if value < u_max else u_max
        total += sum(values.values())
    return total


def dropped_cost(initial: int, max_cycles: int, u_max: int) -> int:
    """``Σ_k u`` of a target nobody visits: it grows by one per step up to ``u_max``."""
    full = max(0, min(max_cycles, u_max - initial))  # steps before it reaches the cap
    growing = full * initial + full * (full + 1) // 2
    return growing + (max_cycles - full) * u_max
