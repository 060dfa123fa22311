"""How a trained team acts: its acting rule and only ``predict_dict``
(:mod:`~sb3_pm.agents.deployment.rule`), the team-at-once forward pass, a team moved to another
graph (:mod:`~sb3_pm.agents.deployment.transfer`) and a saved team's files
(:mod:`~sb3_pm.agents.deployment.saved_teams`)."""
