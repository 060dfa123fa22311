"""Converting a team saved in the old format (``sb3_pm.team/1``, ``sb3_pm.centralized/1``).

Those folders recorded no hyperparameters, so the only way to read them was SB3's ``load``, which
unpickles the ``:serialized:`` entries of each zip with cloudpickle: a crafted file runs code on
loading. Teams are no longer loaded that way (:mod:`sb3_pm.agents.deployment.model_files`); an
old one is refused, and :func:`convert_team` (``sb3-pm convert-team OLD NEW``) converts it:

1. it loads the old team by the old route, **unpickling its files: use it only on teams you trust**
   (ones you trained yourself, or from a source you would run code from);
2. reads each learner's hyperparameters back from the loaded models (:func:`.model_hyperparams`);
3. saves the team in the current format, then loads that folder by the safe route and checks that
   every parameter and optimizer state came through bit for bit.
"""

from __future__ import annotations

import pickle
import zipfile
from pathlib import Path
from typing import Any

import torch as th

from sb3_pm.agents.deployment.saved_teams import MANIFEST, graph_for_saved_team, read_manifest
from sb3_pm.agents.training.learner_record import model_hyperparams
from sb3_pm.errors import InputError


def _load_model_file(algo_class: Any, path: Path, **kwargs: Any) -> Any:
    """``algo_class.load(path, **kwargs)`` (unpickling!), a damaged file as one ``InputError``."""
    try:
        return algo_class.load(path, **kwargs)
    except (RuntimeError, OSError, EOFError, KeyError, zipfile.BadZipFile, pickle.UnpicklingError) as error:
        if isinstance(error, FileNotFoundError):
            raise
        reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise InputError(
            f"{path} cannot be loaded, the file is damaged or not a saved model ({reason})"
        ) from None


def load_old_team(path: str | Path, device: str = "cpu") -> Any:
    """A team saved in an old format, loaded the old way: SB3's ``load`` on each zip, which
    **unpickles** (runs) what the zips hold. For :func:`convert_team` on trusted files only.

    :raises InputError: if the folder does not hold a team in an old format.
    """
    return _load_old(path, device)[0]


def _load_old(path: str | Path, device: str) -> tuple[Any, dict[str, Any]]:
    """:func:`load_old_team`, and the team's manifest."""
    from sb3_pm.agents.training.team import IndependentPPO
    from sb3_pm.sharing.centralized import CentralizedPPO

    folder = Path(path)
    if not (folder / MANIFEST).exists() and (folder / "team" / MANIFEST).exists():
        folder = folder / "team"
    manifest = read_manifest(folder)
    kind = manifest.get("format")
    team_class: Any = next((c for c in (IndependentPPO, CentralizedPPO) if kind in c.OLD_FORMATS), None)
    if team_class is None:
        raise InputError(f"{folder} does not hold a team in an old format (its format is {kind!r})")
    spec = graph_for_saved_team(folder, manifest, None)
    common = {
        "n_agents": int(manifest["n_agents"]),
        "env_kwargs": manifest["env_kwargs"],
        "algo": manifest["algo"],
        "policy": manifest["policy"],
        "n_envs": int(manifest["n_envs"]),
        "seed": int(manifest["seed"]),
        "device": device,
        "deploy_temperature": manifest.get("deploy_temperature"),
    }
    if team_class is CentralizedPPO:
        team = CentralizedPPO(spec, **common, _init_model=False)
    else:
        team = IndependentPPO(spec, **common, deploy_filter=manifest.get("deploy_filter"), _init_models=False)
    try:
        if isinstance(team, CentralizedPPO):
            shared = folder / "shared.zip"
            team.model = _load_model_file(team.algo_class, shared, env=team.venv, device=device)
        else:
            for i, agent in enumerate(team.agents):
                team.models[agent] = _load_model_file(
                    team.algo_class, folder / f"{agent}.zip", env=team.hub.vec_envs[i], device=device
                )
        team._restore_acting_rule(manifest)
    except BaseException:
        team.close()
        raise
    return team, manifest


def _learner_settings(team: Any, manifest: dict[str, Any]) -> None:
    """Give a team loaded the old way the hyperparameters its models were built with."""
    from sb3_pm.sharing.centralized import CentralizedPPO

    pre_settings = "filter_settings" not in manifest and manifest.get("deploy_filter") is not None
    for name, model in team.model_files().items():
        values = model_hyperparams(model, f"{name} of {team.__class__.__name__}")
        if pre_settings:
            # Saved before the manifest held filter_settings, such a team kept its deploy bound in
            # policy_kwargs; its deploy_filter puts it back when it acts, and it trains without.
            for key in ("neglect_bound", "neglect_scope"):
                values.get("policy_kwargs", {}).pop(key, None)
        if isinstance(team, CentralizedPPO):
            team.hyperparams = values
        else:
            team.per_agent[name.removesuffix(".zip")] = values


def _tensors(team: Any) -> list[th.Tensor]:
    tensors: list[th.Tensor] = []
    for model in team.model_files().values():
        names, _ = model._get_torch_save_params()
        for name in names:
            state = _attribute(model, name).state_dict()
            values = state.values() if name == "policy" else _optimizer_tensors(state)
            tensors += [v for v in values if isinstance(v, th.Tensor)]
    return tensors


def _attribute(model: Any, name: str) -> Any:
    from stable_baselines3.common.save_util import recursive_getattr

    return recursive_getattr(model, name)


def _optimizer_tensors(state: dict[str, Any]) -> list[Any]:
    return [value for moments in state["state"].values() for value in moments.values()]


def convert_team(old: str | Path, new: str | Path, overwrite: bool = False, device: str = "cpu") -> Path:
    """Convert a team saved in an old format to the current one; returns the new folder.

    **Loads the old team by unpickling its files: only for teams you trust.** The new folder is
    checked by loading it the safe way: the same parameters and optimizer states, bit for bit.

    :raises InputError: if ``old`` holds no team in an old format, ``new`` is ``old``, or the
        team has a setting the current format cannot record.
    :raises FileExistsError: if ``new`` holds a team and ``overwrite`` is False.
    """
    target = Path(new)
    if target.resolve() in (Path(old).resolve(), (Path(old) / "team").resolve()):
        raise InputError(f"convert-team writes a new folder: {new} is the old team itself")
    team, manifest = _load_old(old, device)
    try:
        _learner_settings(team, manifest)
        saved = team.save(target, overwrite=overwrite)
        loaded = type(team).load(saved, device=device)
        try:
            before, after = _tensors(team), _tensors(loaded)
            same = len(before) == len(after) and all(th.equal(a, b) for a, b in zip(before, after))
        finally:
            loaded.close()
        if not same:
            (saved / MANIFEST).unlink()  # no longer a team: nothing loads it by mistake
            raise InputError(f"{old}: the converted team does not reload with the same parameters")
        return saved
    finally:
        team.close()


__all__ = ["convert_team", "load_old_team"]
