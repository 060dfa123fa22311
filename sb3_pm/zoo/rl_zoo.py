"""Train our algorithms through rl-baselines3-zoo's own ``train``.

rl-zoo picks the algorithm class from its ``rl_zoo3.utils.ALGOS`` table, which knows SB3 and some
sb3-contrib algorithms but neither :class:`~sb3_pm.ppo_dcbf.DCBFPPO` nor sb3-contrib's
``MaskablePPO``. :func:`register_rl_zoo_algos` adds them under these names:

==================  ==========================================
``dcbf_ppo``        :class:`sb3_pm.ppo_dcbf.DCBFPPO` (policy ``DCBFPolicy``)
``maskable_ppo``    :class:`sb3_contrib.MaskablePPO`
``ppo_mask``        the same, under the name older rl-zoo releases used
==================  ==========================================

:func:`main` registers them, then runs rl-zoo's ``train()`` on the given arguments: every rl-zoo
option works (``-conf``, ``-n``, ``--hyperparams``, ``-f``, ``--seed``, ``--eval-freq`` ...), and
our Gymnasium ids are registered already (importing this module runs ``sb3_pm/__init__.py``,
which registers them), so ``--gym-packages`` is optional::

    python -m sb3_pm.zoo --algo dcbf_ppo --env sb3_pm/PersistentMonitoring-paper50-v0 \\
        -conf zoo/dcbf_ppo.yml -n 2048

rl-zoo is an optional extra (``pip install -e ".[zoo]"`` in a checkout, or ``pip install rl_zoo3``);
it is imported only here, lazily.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

# The Gymnasium ids are registered before rl-zoo looks them up: Python runs sb3_pm/__init__.py
# (which calls register_envs) before any module of the package, this one included.
from sb3_pm.zoo.registry import ALGORITHMS, import_path

#: rl-zoo algorithm name -> our registry name (:data:`sb3_pm.zoo.registry.ALGORITHMS`).
RL_ZOO_ALGOS: dict[str, str] = {
    "dcbf_ppo": "dcbf_ppo",
    "maskable_ppo": "maskable_ppo",
    "ppo_mask": "maskable_ppo",
}


def _require_rl_zoo() -> None:
    try:
        import rl_zoo3  # noqa: F401
    except ImportError as error:  # pragma: no cover - depends on the install
        raise ImportError(
            "rl-baselines3-zoo is not installed: pip install rl_zoo3"
            ' (or, in a checkout of sb3_pm: pip install -e ".[zoo]")'
        ) from error


def register_rl_zoo_algos() -> list[str]:
    """Add our algorithms to rl-zoo's ``ALGOS`` table (idempotent); return the names added.

    Also lets rl-zoo's hyperparameter search (``-optimize``) sample them: they take PPO's
    arguments, so PPO's sampler and converter apply unchanged.
    """
    _require_rl_zoo()
    from rl_zoo3.utils import ALGOS

    added = []
    for zoo_name, our_name in RL_ZOO_ALGOS.items():
        if zoo_name not in ALGOS:
            ALGOS[zoo_name] = import_path(ALGORITHMS[our_name])
            added.append(zoo_name)
    try:
        from rl_zoo3.hyperparams_opt import HYPERPARAMS_CONVERTER, HYPERPARAMS_SAMPLER
    except ImportError:  # pragma: no cover - optuna is part of rl-zoo's own requirements
        return added
    for zoo_name in RL_ZOO_ALGOS:
        HYPERPARAMS_SAMPLER.setdefault(zoo_name, HYPERPARAMS_SAMPLER["ppo"])
        HYPERPARAMS_CONVERTER.setdefault(zoo_name, HYPERPARAMS_CONVERTER["ppo"])
    return added


def main(argv: Sequence[str] | None = None) -> None:
    """Register our algorithms, then run ``rl_zoo3.train.train()`` on ``argv``.

    :param argv: rl-zoo ``train`` arguments (default: this process's command line).
    """
    register_rl_zoo_algos()
    from rl_zoo3.train import train

    if argv is not None:
        # rl-zoo's train() parses sys.argv itself; hand it ours.
        sys.argv = [sys.argv[0] if sys.argv else "sb3_pm.zoo", *argv]
    train()


__all__ = ["RL_ZOO_ALGOS", "main", "register_rl_zoo_algos"]
