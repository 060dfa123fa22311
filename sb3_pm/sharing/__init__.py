"""The parameter-*sharing* alternative to independent learners, built on SuperSuit.

One network acts for every agent: SuperSuit turns the PettingZoo env into a vector env whose
entries are (env copy, agent) pairs, and a single SB3 model trains on all of them. This is the
usual baseline in the MARL literature and the opposite of this project's fully decentralized
learners, which share nothing. See ``examples/parameter_sharing_supersuit.py``.
"""

from sb3_pm.sharing.supersuit_vec_env import MaskedVecEnv, make_parameter_sharing_vec_env

__all__ = ["MaskedVecEnv", "make_parameter_sharing_vec_env"]
