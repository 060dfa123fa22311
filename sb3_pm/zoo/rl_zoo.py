"""rl-baselines3-zoo's own commands, with our algorithms, ids and configs: ``python -m sb3_pm.zoo``.

rl-zoo picks the algorithm class from its ``rl_zoo3.utils.ALGOS`` table, which knows SB3 and some
sb3-contrib algorithms but neither :class:`~sb3_pm.ppo_dcbf.DCBFPPO` nor sb3-contrib's
``MaskablePPO``. :func:`register_rl_zoo_algos` adds them under these names:

==================  ==========================================
``dcbf_ppo``        :class:`sb3_pm.ppo_dcbf.DCBFPPO` (policy ``DCBFPolicy``)
``maskable_ppo``    :class:`sb3_contrib.MaskablePPO`
``ppo_mask``        the same, under the name older rl-zoo releases used
==================  ==========================================

:func:`main` then runs rl-zoo's own module for the command, with rl-zoo's own arguments::

    python -m sb3_pm.zoo train --algo dcbf_ppo --env sb3_pm/PersistentMonitoring-paper50-v0 -n 2048
    python -m sb3_pm.zoo enjoy --algo dcbf_ppo --env sb3_pm/PersistentMonitoring-paper50-v0 -f logs
    python -m sb3_pm.zoo record_video --algo dcbf_ppo --env sb3_pm/PersistentMonitoring-paper50-v0 -f logs
    python -m sb3_pm.zoo optimize --algo dcbf_ppo --env sb3_pm/PersistentMonitoring-paper50-v0 -n 2048

On top of rl-zoo:

* our Gymnasium ids are registered (importing this module runs ``sb3_pm/__init__.py``), so
  ``--gym-packages`` is never needed, also for ``record_video``, which has no such option;
* ``-conf`` takes a shipped config by name (``-conf dcbf_ppo``, the files of the repository's
  ``zoo/`` folder, installed as ``sb3_pm.configs``) as well as a path; without ``-conf``, an
  ``sb3_pm/`` id uses the shipped ``<algo>.yml`` (rl-zoo's own files know none of our ids);
* when acting (``enjoy``, ``record_video``), ``maskable_ppo`` and ``dcbf_ppo`` take their action
  masks from the observation's ``action_mask`` (rl-zoo passes none, and an unmasked
  ``MaskablePPO`` picks illegal moves);
* ``optimize`` (rl-zoo's ``-optimize``) samples ``dcbf_ppo`` with PPO's sampler plus the GAT, the
  estimator and the DCBF filter settings, merged into the config's ``policy_kwargs``
  (:mod:`sb3_pm.zoo.rl_zoo_search`).

A command-line without a command (``python -m sb3_pm.zoo --algo ...``) is ``train``. rl-zoo is an
optional extra (``pip install -e ".[zoo]"`` in a checkout, or ``pip install rl_zoo3 pandas``); it
is imported only here, lazily.
"""

from __future__ import annotations

import runpy
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

# The Gymnasium ids are registered before rl-zoo looks them up: Python runs sb3_pm/__init__.py
# (which calls register_envs) before any module of the package, this one included.
from sb3_pm.errors import UsageError
from sb3_pm.zoo.registry import ALGORITHMS, import_path
from sb3_pm.zoo.shipped import resolve_config_path, shipped_names

#: rl-zoo algorithm name -> our registry name (:data:`sb3_pm.zoo.registry.ALGORITHMS`).
RL_ZOO_ALGOS: dict[str, str] = {
    "dcbf_ppo": "dcbf_ppo",
    "maskable_ppo": "maskable_ppo",
    "ppo_mask": "maskable_ppo",
}
#: The commands :func:`main` runs, and rl-zoo's module for each.
COMMANDS: dict[str, str] = {
    "train": "rl_zoo3.train",
    "optimize": "rl_zoo3.train",
    "enjoy": "rl_zoo3.enjoy",
    "record_video": "rl_zoo3.record_video",
}
#: The prefix of our Gymnasium ids.
OUR_IDS = "sb3_pm/"


def _require_rl_zoo() -> None:
    try:
        import rl_zoo3  # noqa: F401
    except ImportError as error:  # pragma: no cover - depends on the install
        raise ImportError(
            "rl-baselines3-zoo is not installed: pip install rl_zoo3"
            ' (or, in a checkout of sb3_pm: pip install -e ".[zoo]")'
        ) from error


def acting_with_observed_masks(algo_class: type) -> type:
    """A subclass of the maskable ``algo_class`` whose ``predict`` takes the action masks from the
    observation's ``action_mask`` when it is given none, as rl-zoo's ``enjoy`` and
    ``record_video`` give none."""

    def predict(self: Any, observation: Any, *args: Any, action_masks: Any = None, **kwargs: Any) -> Any:
        if action_masks is None and isinstance(observation, dict) and "action_mask" in observation:
            action_masks = np.asarray(observation["action_mask"]).astype(bool)
        return algo_class.predict(self, observation, *args, action_masks=action_masks, **kwargs)  # type: ignore[attr-defined]

    return type(algo_class.__name__, (algo_class,), {"predict": predict, "__module__": algo_class.__module__})


def register_rl_zoo_algos(acting: bool = False) -> list[str]:
    """Add our algorithms to rl-zoo's ``ALGOS`` table; return the names added.

    :param acting: register them as :func:`acting_with_observed_masks` subclasses (for ``enjoy``
        and ``record_video``), replacing plain ones registered before.
    """
    _require_rl_zoo()
    from rl_zoo3.utils import ALGOS

    added = []
    for zoo_name, our_name in RL_ZOO_ALGOS.items():
        algo_class = import_path(ALGORITHMS[our_name])
        if acting:
            ALGOS[zoo_name] = acting_with_observed_masks(algo_class)
        elif zoo_name not in ALGOS:
            ALGOS[zoo_name] = algo_class
        else:
            continue
        added.append(zoo_name)
    return added


def shipped_config(name: str) -> Path | None:
    """The shipped rl-zoo config ``name`` (``dcbf_ppo``, ``dcbf_ppo.yml`` or ``zoo/dcbf_ppo.yml``),
    or ``None`` (:func:`~sb3_pm.zoo.shipped.resolve_config_path`, the rule ``sb3-pm`` names
    configs by)."""
    try:
        return resolve_config_path(name)
    except FileNotFoundError:
        return None


def _option(args: list[str], *names: str) -> tuple[int, str] | None:
    """The index and value of the first of ``names`` in ``args`` (``--x v`` or ``--x=v``)."""
    for index, arg in enumerate(args):
        for name in names:
            if arg == name and index + 1 < len(args):
                return index + 1, args[index + 1]
            if arg.startswith(name + "="):
                return index, arg.split("=", 1)[1]
    return None


def resolve_config(args: Sequence[str]) -> list[str]:
    """``args`` with ``-conf``/``--conf-file`` naming an existing file: a shipped config's name is
    replaced by its path, and an ``sb3_pm/`` id without ``-conf`` gets the shipped ``<algo>.yml``.

    :raises UsageError: for a ``-conf`` that is neither a file nor a shipped config.
    """
    args = list(args)
    given = _option(args, "-conf", "--conf-file")
    if given is not None:
        index, value = given
        path = shipped_config(value)
        if path is None and "." not in value.removesuffix(".yml"):  # a dotted name: rl-zoo's module
            raise UsageError(
                f"-conf {value!r} is neither a file nor a shipped config ({', '.join(shipped_names())})"
            )
        if path is not None:
            args[index] = str(path) if args[index] == value else f"{args[index].split('=', 1)[0]}={path}"
        return args
    env, algo = _option(args, "--env"), _option(args, "--algo")
    if env is not None and env[1].startswith(OUR_IDS) and algo is not None:
        path = shipped_config(algo[1])
        if path is not None:
            args += ["-conf", str(path)]
    return args


def main(argv: Sequence[str] | None = None) -> None:
    """Run rl-zoo's command ``argv[0]`` (``train``, ``enjoy``, ``record_video`` or ``optimize``;
    none: ``train``) on the rest of ``argv`` (default: this process's command line), as the module
    docstring describes."""
    args = list(sys.argv[1:] if argv is None else argv)
    command = args.pop(0) if args and args[0] in COMMANDS else "train"
    if args and not args[0].startswith("-"):
        raise UsageError(f"unknown command {args[0]!r}: use one of {', '.join(COMMANDS)}")
    if command in ("train", "optimize"):
        args = resolve_config(args)
    register_rl_zoo_algos(acting=command in ("enjoy", "record_video"))
    if command == "optimize":
        from sb3_pm.zoo.rl_zoo_search import register_samplers

        if "-optimize" not in args and "--optimize-hyperparameters" not in args:
            args.append("-optimize")
        register_samplers(args)
    elif command == "train":
        from sb3_pm.zoo.rl_zoo_search import register_samplers

        register_samplers(args)  # a train command-line may carry -optimize itself
    # rl-zoo's scripts parse sys.argv themselves; hand them ours.
    sys.argv = [f"sb3_pm.zoo {command}", *args]
    if command == "enjoy":
        from rl_zoo3.enjoy import enjoy

        enjoy()
    elif command == "record_video":
        runpy.run_module(COMMANDS[command], run_name="__main__", alter_sys=True)
    else:
        from rl_zoo3.train import train

        train()


__all__ = ["COMMANDS", "RL_ZOO_ALGOS", "main", "register_rl_zoo_algos", "resolve_config", "shipped_config"]
