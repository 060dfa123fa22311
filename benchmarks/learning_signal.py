"""How much a team's PPO updates move its policy: a diagnostic for configs that do not learn.

    python benchmarks/learning_signal.py --config ippo_paper --graph paper-50 [--timesteps 1000]
        [--seed 0] [--hyperparams KEY:VALUE ...] [--env-kwargs KEY:VALUE ...]

Trains a team for ``--timesteps`` steps per learner with the config's entry for the graph (the same
``KEY:VALUE`` overrides as ``sb3-pm train``), then, for every learner, on its last rollout:

* ``free``: the fraction of steps whose DCBF mask allowed more than one action (the only steps on
  which the actor's choice matters and PPO's policy gradient is nonzero);
* ``entropy``: the policy's mean entropy on those steps (nats);
* ``|d log pi|``: the mean absolute change of the taken action's log-probability on those steps,
  between the parameters before and after the last update (how far that update moved the policy);
* ``EV``: the critic's explained variance of the rollout's returns after the update;
* ``return``: the mean discounted return target of the rollout (the scale the critic must fit).

Figures printed, not asserted: they diagnose, e.g., a critic that cannot fit unscaled returns, or a
learning rate too small for the few free steps of a dwelling team.
"""

from __future__ import annotations

import argparse
import copy

import numpy as np
import torch as th


def free_step_signal(model, before: dict) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """The figures above for one learner whose rollout buffer holds its last rollout."""
    buffer = model.rollout_buffer
    size = buffer.buffer_size * buffer.n_envs
    flat = buffer.generator_ready  # SB3 flattens the buffer in place during train()

    def rows(array: np.ndarray) -> th.Tensor:
        return th.as_tensor(array if flat else array.reshape(size, *array.shape[2:]))

    observations = {key: rows(value) for key, value in buffer.observations.items()}
    masks = rows(buffer.action_masks).reshape(size, -1)
    actions = rows(buffer.actions).reshape(size)
    after = copy.deepcopy(model.policy.state_dict())
    with th.no_grad():
        values, log_prob_after, entropy = model.policy.evaluate_actions(observations, actions, masks)
        model.policy.load_state_dict(before)
        _, log_prob_before, _ = model.policy.evaluate_actions(observations, actions, masks)
        model.policy.load_state_dict(after)
    free = masks.sum(-1) > 1
    returns = rows(buffer.returns).reshape(size)
    explained = 1.0 - float(th.var(returns - values.reshape(size))) / max(float(th.var(returns)), 1e-12)
    return {
        "free": float(free.float().mean()),
        "entropy": float(entropy[free].mean()) if free.any() else 0.0,
        "|d log pi|": float((log_prob_after - log_prob_before)[free].abs().mean()) if free.any() else 0.0,
        "EV": explained,
        "return": float(returns.mean()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--config", default="ippo")
    parser.add_argument("--graph", default="paper-50")
    parser.add_argument("--timesteps", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--hyperparams", nargs="*", default=[], metavar="KEY:VALUE")
    parser.add_argument("--env-kwargs", nargs="*", default=[], metavar="KEY:VALUE")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    th.set_num_threads(args.threads)

    from stable_baselines3.common.callbacks import BaseCallback

    from sb3_pm.agents.training.team import IndependentPPO
    from sb3_pm.commands.train import parse_overrides
    from sb3_pm.zoo.config import load_config

    overrides = parse_overrides(args.hyperparams, "--hyperparams")
    if args.env_kwargs:
        overrides["env_kwargs"] = parse_overrides(args.env_kwargs, "--env-kwargs")
    config = load_config(args.config, args.graph, overrides=overrides)
    team = IndependentPPO.from_config(config, args.graph, seed=args.seed)
    snapshots: dict[str, dict] = {}

    class KeepParameters(BaseCallback):
        """Copies the policy's parameters at the end of each rollout, i.e. just before train()."""

        def __init__(self, agent: str) -> None:
            super().__init__()
            self.agent = agent

        def _on_step(self) -> bool:
            return True

        def _on_rollout_end(self) -> None:
            snapshots[self.agent] = copy.deepcopy(self.model.policy.state_dict())

    team.learn(args.timesteps, callback=KeepParameters)
    print(f"{args.config} on {args.graph}, {args.timesteps} steps per learner, seed {args.seed}")
    for agent, model in team.models.items():
        figures = free_step_signal(model, snapshots[agent])
        print(agent, "  ".join(f"{key} {value:.4g}" for key, value in figures.items()))
    team.close()


if __name__ == "__main__":
    main()
