"""Independent learners: :mod:`sb3_pm.agents.team` (``IndependentPPO``, one learner per agent) and
:mod:`sb3_pm.agents.multiplexer` (one parallel env seen as one vec env per learner).

Both load on first import of their module; this package itself imports nothing.
"""
