"""Persistent monitoring on a graph, version 0: the PettingZoo-style versioned entry point.

The environment, its arguments and its spaces are documented in
:mod:`sb3_pm.envs.persistent_monitoring`; this module only re-exports its constructors under the
versioned name, as PettingZoo's ``*_vN`` modules do::

    from sb3_pm.envs import persistent_monitoring_v0
    env = persistent_monitoring_v0.parallel_env(graph="paper-50", n_agents=4)
    observations, infos = env.reset(seed=0)

Version history
---------------
v0: first release.
"""

from sb3_pm.envs.persistent_monitoring import env, parallel_env, raw_env

__all__ = ["env", "parallel_env", "raw_env"]
