"""The PettingZoo-to-SB3 bridge: one parallel env seen as one ``VecEnv`` per learner
(:mod:`~sb3_pm.agents.multiplexing.multiplexer`), the learners' threads, turn order and random
streams, update slots and wait deadlines."""
