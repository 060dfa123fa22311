"""Training a team: :class:`~sb3_pm.agents.training.team.IndependentPPO` (one SB3 learner per
agent), what every trained team shares (:mod:`~sb3_pm.agents.training.learned_team`), the learners'
construction and callbacks, the stacked rollout passes and checkpoints with resume."""
