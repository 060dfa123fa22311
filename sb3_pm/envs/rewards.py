"""Per-agent rewards as a weighted sum of named terms (docs/METHOD.md "Reward", paper eq. 5-8).

Each term is computed from what the agent itself did, found and remembers, so every reward is
local: no agent's reward depends on another agent's observations or map. Terms:

``collision``
    -3 when another agent shares the agent's node (eq. 6).
``momentum``
    a counter reset each episode, +1 when the agent's node had u > 0 as it arrived,
    else -1; the reward carries the counter's value (eq. 8). "Had u > 0 as it arrived"
    is the value its presence acted on, so a visit that clears u = 1 counts as useful.
``change``
    Ū - U_i, paid at the episode's last step (eq. 7). U_i is the episode's sum over
    steps and nodes of the agent's mental-map uncertainty; Ū is the mean of U_i over
    the agent's previous 10 episodes (0 while it has none).
``reduction``
    the agent's marginal effect on total target uncertainty this step: how much lower u
    is at its node than it would be without it (2 for u > 0, 1 for u = 0, less at the
    cap; 0 when another agent is there too, since that one does the work alone). Local,
    dense, and aligned with the avg_uncertainty metric.
``clearing``
    how much the agent actually lowers u at its node this step: 1 on a target with
    u > 0 where it is alone, else 0. Unlike ``reduction`` it pays nothing for guarding a
    target that is already at 0, which ``reduction`` pays at half the clearing rate
    with no travel cost, so it removes the incentive to idle on cleared targets.
``territory``
    what ``clearing`` pays, but only on the targets of the agent's own territory: a
    fixed, balanced split of the site's targets among the agents, which every agent
    derives from the road network, the target list and its own index
    (:mod:`sb3_pm.graphs.territories`), so no communication is needed. A convention that
    tells otherwise identical learners apart, aimed at runs in which two learners
    contest the same targets (not in the paper).

Presets: ``paper`` = 0.05 x (collision + change + momentum), as in the paper; ``reduction`` =
1.0 x reduction + 0.05 x collision.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from typing import Any

import numpy as np

from sb3_pm.envs.core import StepOutcome
from sb3_pm.errors import InputError

TERMS = (
    "collision",
    "momentum",
    "change",
    "reduction",
    "clearing",
    "territory",
)
REWARD_PRESETS: dict[str, dict[str, float]] = {
    "paper": {"collision": 0.05, "change": 0.05, "momentum": 0.05},
    "reduction": {"reduction": 1.0, "collision": 0.05},
}
COLLISION_PENALTY = -3.0
CHANGE_WINDOW = 10


def resolve_reward(reward: str | Mapping[str, float]) -> dict[str, float]:
    """A preset name or a ``{term: weight}`` mapping -> validated weights."""
    if isinstance(reward, str):
        if reward not in REWARD_PRESETS:
            raise InputError(f"unknown reward preset {reward!r}; presets are {sorted(REWARD_PRESETS)}")
        return dict(REWARD_PRESETS[reward])
    weights = {str(k): float(v) for k, v in dict(reward).items()}
    unknown = sorted(set(weights) - set(TERMS))
    if unknown:
        raise InputError(f"unknown reward terms {unknown}; terms are {list(TERMS)}")
    if not weights:
        raise InputError("reward needs at least one term")
    return weights


class RewardComputer:
    """Stateful per-agent reward terms for one environment (momentum counters, episode history).

    :param weights: ``{term: weight}``, see :func:`resolve_reward`.
    :param n_agents: team size.
    :param u_max: the uncertainty cap (for the ``reduction`` counterfactual).
    """

    def __init__(self, weights: Mapping[str, float], n_agents: int, u_max: int) -> None:
        self.weights = dict(weights)
        self.n_agents = n_agents
        self.u_max = u_max
        self.momentum = np.zeros(n_agents, dtype=np.float64)
        self.history: list[deque[float]] = [deque(maxlen=CHANGE_WINDOW) for _ in range(n_agents)]

    def state_dict(self) -> dict[str, Any]:
        """The running terms (momentum, the ``change`` history), as plain values (a checkpoint's)."""
        return {"momentum": self.momentum.copy(), "history": [list(window) for window in self.history]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Put back a :meth:`state_dict` of a computer for the same team."""
        self.momentum = np.asarray(state["momentum"], dtype=np.float64).copy()
        self.history = [
            deque((float(v) for v in window), maxlen=CHANGE_WINDOW) for window in state["history"]
        ]

    def forget_history(self) -> None:
        """Forget past episodes (a new agent lifetime): ``change`` starts from no history again."""
        for window in self.history:
            window.clear()

    def reset(self) -> None:
        """New episode: momentum restarts; the change history is kept (it spans episodes)."""
        self.momentum[:] = 0.0

    def step(
        self,
        outcome: StepOutcome,
        alone_on_target: np.ndarray,
        last_step: bool,
        map_sums: np.ndarray,
        on_own_territory: np.ndarray | None = None,
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Rewards for one step.

        :param outcome: the move just made.
        :param alone_on_target: ``(n_agents,)`` bool, the agent's node is a target and no other
            agent is on it (the only case in which ``reduction`` and ``clearing`` pay).
        :param last_step: the episode ends with this step (``change`` is paid).
        :param map_sums: ``(n_agents,)`` this episode's U_i so far, including this step.
        :param on_own_territory: ``(n_agents,)`` bool, the agent's node is a target of its own
            territory (needed by ``territory`` only).
        :return: ``(n_agents,)`` float rewards and each weighted term's ``(n_agents,)`` values.
        """
        terms: dict[str, np.ndarray] = {}
        w = self.weights
        if "collision" in w:
            terms["collision"] = w["collision"] * np.where(outcome.collided, COLLISION_PENALTY, 0.0)
        if "momentum" in w:
            self.momentum += np.where(outcome.u_before > 0, 1.0, -1.0)
            terms["momentum"] = w["momentum"] * self.momentum
        if "reduction" in w:
            counterfactual = np.minimum(outcome.u_before + 1, self.u_max)
            removed = counterfactual - outcome.u_after
            terms["reduction"] = w["reduction"] * np.where(alone_on_target, removed, 0.0)
        if "clearing" in w or "territory" in w:
            lowered = np.maximum(outcome.u_before - outcome.u_after, 0)
            clears = alone_on_target & (lowered > 0)
            if "clearing" in w:
                terms["clearing"] = w["clearing"] * np.where(clears, lowered, 0.0)
            if "territory" in w:
                if on_own_territory is None:
                    raise InputError("the territory reward term needs each agent's territory")
                terms["territory"] = w["territory"] * np.where(clears & on_own_territory, lowered, 0.0)
        if "change" in w:
            change = np.zeros(self.n_agents)
            if last_step:
                for agent, window in enumerate(self.history):
                    if window:
                        change[agent] = float(np.mean(window)) - map_sums[agent]
                    window.append(float(map_sums[agent]))
            terms["change"] = w["change"] * change
        total = np.zeros(self.n_agents)
        for values in terms.values():
            total += values
        return total, terms
