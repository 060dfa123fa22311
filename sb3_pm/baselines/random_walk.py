"""``random``: every agent picks a destination uniformly from its reachable set.

See docs/METHOD.md, "Baselines".
"""

from __future__ import annotations

import numpy as np

from sb3_pm.team_interface import Observation, Team


class RandomTeam(Team):
    """Uniform over each agent's ``action_mask``, drawn from the team's seeded rng.

    Decentralized: it reads nothing but each agent's own mask. ``deterministic`` is ignored,
    since the randomness *is* the policy.
    """

    name = "random"
    omniscient = False

    def predict_dict(
        self, observations: dict[str, Observation], deterministic: bool = True
    ) -> dict[str, int]:
        agents = list(observations)
        masks = np.stack([np.asarray(observations[a]["action_mask"], dtype=bool) for a in agents])
        # argmax over iid uniform scores restricted to the mask is a uniform draw from the mask,
        # one vectorized call for the whole team instead of one rng.choice per agent.
        scores = np.where(masks, self.rng.random(masks.shape) + 1.0, 0.0)
        choices = scores.argmax(axis=1)
        return {agent: int(choice) for agent, choice in zip(agents, choices)}
