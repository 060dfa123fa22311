"""A saved team's SB3 zips, read without running anything stored in them.

Each learner of a saved team is an SB3 zip as ``model.save`` writes it, so SB3 users can open it
themselves. SB3's own ``load`` unpickles the ``:serialized:`` entries of the zip's ``data`` (the
spaces, schedules, last observations ...) with cloudpickle, which runs whatever a crafted file
holds. A team is never loaded that way: it is rebuilt through its constructor from its manifest
(plain JSON), and :func:`restore_model` then takes from each zip only

* the tensors: every ``*.pth`` (``policy.pth``, ``policy.optimizer.pth``, the estimator's
  optimizer, ``pytorch_variables.pth``), read with ``torch.load(..., weights_only=True)``, which
  rebuilds tensors and plain containers and refuses anything else;
* the counters of ``data`` that are plain JSON numbers (:data:`COUNTERS`); every ``:serialized:``
  entry is skipped unread.
"""

from __future__ import annotations

import io
import json
import pickle
import zipfile
from pathlib import Path
from typing import Any

import torch as th

from sb3_pm.errors import InputError

#: The learner counters restored from a zip's ``data`` (plain JSON numbers there).
COUNTERS = (
    "num_timesteps",
    "_total_timesteps",
    "_num_timesteps_at_start",
    "_n_updates",
    "_episode_num",
    "_current_progress_remaining",
)


def read_model_file(path: Path, device: str | th.device = "cpu") -> tuple[dict[str, Any], dict[str, Any]]:
    """``(counters, tensors)`` of an SB3 zip: :data:`COUNTERS` from ``data`` and every ``*.pth``
    by its name without the suffix (``policy``, ``policy.optimizer``, ``pytorch_variables`` ...).

    :raises InputError: if the file is not such a zip, naming it and the reason.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()
            if "data" not in names:
                raise InputError(f"{path} is not a saved SB3 model (it has no data entry)")
            data = json.loads(archive.read("data"))
            tensors = {
                name[: -len(".pth")]: th.load(
                    io.BytesIO(archive.read(name)), map_location=device, weights_only=True
                )
                for name in names
                if name.endswith(".pth")
            }
    except (zipfile.BadZipFile, OSError, EOFError, RuntimeError, ValueError, pickle.UnpicklingError) as error:
        if isinstance(error, (FileNotFoundError, InputError)):
            raise
        reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise InputError(
            f"{path} cannot be loaded, the file is damaged or not a saved model ({reason})"
        ) from None
    if not isinstance(data, dict):
        raise InputError(f"{path} is not a saved SB3 model (its data is not a mapping)")
    counters = {}
    for key in COUNTERS:
        value = data.get(key)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            counters[key] = value
    return counters, tensors


def restore_model(model: Any, path: Path, device: str | th.device = "cpu") -> None:
    """Load the parameters, optimizer states and counters of the zip at ``path`` into ``model``, a
    learner built with the settings it was saved with.

    :raises InputError: if the zip lacks a state ``model`` has, or its tensors do not fit.
    """
    counters, tensors = read_model_file(path, device)
    state_dicts, variables = model._get_torch_save_params()
    missing = [name for name in state_dicts if name not in tensors]
    if missing:
        raise InputError(f"{path} does not hold {', '.join(missing)} of a {type(model).__name__} learner")
    from stable_baselines3.common.save_util import recursive_getattr

    try:
        for name in state_dicts:
            # A policy checks every key (strict); an optimizer checks its parameter groups.
            recursive_getattr(model, name).load_state_dict(tensors[name])
        saved_variables = tensors.get("pytorch_variables") or {}
        for name in variables:
            if name not in saved_variables:
                raise InputError(f"{path} does not hold the variable {name}")
            with th.no_grad():
                recursive_getattr(model, name).copy_(saved_variables[name])
    except (RuntimeError, ValueError, KeyError, TypeError, AttributeError) as error:
        reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise InputError(
            f"{path} does not fit the team's {type(model).__name__} learner ({reason})"
        ) from None
    for key, value in counters.items():
        setattr(model, key, value)
    if getattr(model, "use_sde", False):
        model.policy.reset_noise()


__all__ = ["COUNTERS", "read_model_file", "restore_model"]
