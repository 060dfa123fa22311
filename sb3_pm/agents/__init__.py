"""Decentralized teams of independent learners, by job:

* :mod:`sb3_pm.agents.deployment`: how a trained team acts (one acting rule, one ``predict_dict``) and
  how it is saved;
* :mod:`sb3_pm.agents.multiplexing`: one PettingZoo parallel env seen as one SB3 ``VecEnv`` per
  learner, with the learners' threads and random streams;
* :mod:`sb3_pm.agents.training`: ``IndependentPPO`` (one learner per agent), its learners,
  callbacks and checkpoints.

Each subpackage imports only those listed above it. This package itself imports nothing (torch
loads on first use of a learner).
"""
