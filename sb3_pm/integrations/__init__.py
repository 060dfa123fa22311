"""Bridges to other multi-agent RL libraries.

- :mod:`sb3_pm.integrations.flat_env`: the monitoring env with one flat observation vector per
  agent and the action mask in the infos (needs nothing beyond the package's own requirements).
- :mod:`sb3_pm.integrations.benchmarl_task`: that env as a BenchMARL task, and a trained BenchMARL
  policy as a :class:`~sb3_pm.team_interface.Team` (the optional extra ``benchmarl``).

Nothing here is imported by ``import sb3_pm``.
"""
