"""Training speed of an independent team, next to stock SB3 PPO measured in the same run.

    python benchmarks/train_speed.py [--timesteps 1000] [--graphs paper-50 paper-200] [--algo dcbf_ppo]
                                     [--config ippo] [--repeats 1] [--threads 2] [--profile]
                                     [--updates side-by-side serial] [--rollouts stacked serial]
                                     [--devices cpu cuda] [--attention batch map]
                                     [--agents 4] [--update-slots auto all]

Prints agent-steps per second (every learner's steps, summed: a 4-agent team at T steps per
learner takes 4T) for a team of ``--agents`` (default 4) on each graph, and env-steps per second for SB3 PPO
(MlpPolicy) on CartPole-v1 with 8 envs. Both include PPO's train() phases. Short runs: a warm-up
rollout is not timed, so the figures are throughput, not start-up cost.

The team uses the config's entry for the graph (hyperparameters and ``policy_kwargs``, as
``sb3-pm train`` would); ``--n-envs``/``--n-steps`` override it, and ``batch_size`` follows
``n_steps`` only when overridden. ``--n-epochs`` overrides the passes over each rollout (several
values for the ratios in one run). With ``--repeats R`` each team figure is the median of R timed
runs (the CPU may be shared; the load average is printed).

``--updates`` picks how the learners' update phases run: ``side-by-side`` (the default,
``IndependentPPO(concurrent_updates=True)``, each learner's ``train()`` in its own thread) and/or
``serial`` (one after another); both give the same parameters, so listing both measures the gain.

``--rollouts`` picks how the learners' rollout passes run: ``stacked`` (the default,
``IndependentPPO.batched_rollouts``: one team pass per joint step for all learners,
:mod:`sb3_pm.agents.training.rollout_batching`) and/or ``serial`` (each learner its own pass); both give the
same parameters, so listing both measures the gain.

``--devices`` trains the team's learners on each torch device listed, for the ratios in one run:
``cpu``, ``cuda``, or ``cpu+cuda`` (rollouts on the CPU, each update phase on the GPU:
``IndependentPPO.update_device``). CartPole always runs on the CPU, as SB3 recommends for
MlpPolicy. With ``cuda`` the learners' update phases run one after another (side-by-side threads
are for CPU learners), so ``--updates`` changes only the other rows.

``--attention`` picks when the dense attention runs the chunked kernel
(:func:`sb3_pm.policies.attention.use_chunked`): ``batch`` (the default: when one map's scores or
the whole minibatch's are large, so a PPO minibatch on 200 nodes takes it) and/or ``map`` (the
rule before it: only when one map's scores are large, never at one head below 256 nodes). Both give
the same parameters bit for bit (``tests/test_attention_kernels.py``), so listing both measures the
gain.

``--update-slots`` picks how many learners may run their update phase at once
(:mod:`sb3_pm.agents.multiplexing.update_slots`): ``auto`` (the default: one per core over torch's threads),
``all`` (every learner, the rule before it) or a number. The parameters are the same whatever the
count, so listing several measures the gain (it shows with many learners: ``--agents 16``).

``--profile`` adds, for each graph, where the team's wall time goes: the joint environment step,
the learners' rollout inference (action, value and DCBF mask), PPO's ``train()``, the estimator
fit, and the rest (buffers, callbacks, the multiplexer's hand-offs). With serial updates only the
learner holding the baton runs, so these phases add up to the wall time; with side-by-side
updates the learners' update phases overlap, so their sums exceed it and no rest is printed.

It also prints two bounds from the same run, for what faster code in one part could buy at most:

* **rollout inference free**: the team's speed if its rollout inference (the acting pass and the
  draws; the tensor conversions around them count as "rest") took no time at all: the wall time
  less that phase. The rollout phase runs on one core between update phases, overlapped by
  nothing but a learner's first update starting while its teammates finish their last step, so
  this is an upper bound for any speed-up of the acting pass.
* **updates alone**: the paper's budget if nothing but the update phases (``train()`` and the
  estimator fit) ran, their summed time spread perfectly over the cores this process may use
  (:func:`sb3_pm.machine.usable_cores`): a lower bound on the budget's time with the update's arithmetic
  as it is, and its speed, as a ratio to CartPole, an upper bound for any speed-up of the rest
  (rollouts, environment, hand-offs). Measured with ``--updates serial`` it is a bound in the
  strict sense; side by side, the threads' summed time includes their contention (the memory
  bus, the interpreter lock) and so overstates it. Not printed for updates on a GPU.
"""

from __future__ import annotations

import argparse
import itertools
import os
import statistics
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import torch as th

_PHASES_LOCK = threading.Lock()


def _timed(phases: dict[str, float], name: str, method: Callable[..., Any]) -> Callable[..., Any]:
    """``method``, adding its wall time to ``phases[name]`` (learners may run it at the same time)."""

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return method(*args, **kwargs)
        finally:
            with _PHASES_LOCK:
                phases[name] += time.perf_counter() - start

    return wrapper


def _instrument(team: Any, phases: dict[str, float]) -> Callable[[], None]:
    """Time the team's phases (see the module docstring) into ``phases``; returns what undoes the
    patches of classes."""
    from sb3_pm.agents.training.rollout_batching import RolloutBatcher
    from sb3_pm.callbacks import EstimatorCallback

    team.hub._joint_step = _timed(phases, "environment step", team.hub._joint_step)
    for model in team.models.values():
        policy = model.policy
        # DCBFPPO's rollout passes (its own, or the batcher's below) and draws; the values of
        # truncated episodes' last observations
        for name in ("rollout_heads", "sample_masked", "predict_values"):
            if hasattr(policy, name):
                setattr(policy, name, _timed(phases, "rollout inference", getattr(policy, name)))
        model.train = _timed(phases, "train()", model.train)
    fit, heads = EstimatorCallback.fit, RolloutBatcher.heads
    EstimatorCallback.fit = _timed(phases, "estimator fit", fit)  # type: ignore[method-assign]
    RolloutBatcher.heads = _timed(phases, "rollout inference", heads)  # type: ignore[method-assign]

    def undo() -> None:
        EstimatorCallback.fit = fit  # type: ignore[method-assign]
        RolloutBatcher.heads = heads  # type: ignore[method-assign]

    return undo


def print_bounds(
    phases: dict[str, float],
    elapsed: float,
    agent_steps: int,
    cartpole: float,
    agents: int,
    updates_on_cpu: bool = True,
) -> None:
    """The two bounds of ``--profile`` (module docstring) from one timed run's ``phases``."""
    inference = phases.get("rollout inference", 0.0)
    if inference < elapsed:
        free = agent_steps / (elapsed - inference)
        print(
            f"    {'bound: rollout inference free':<44} {free:7.0f} agent-steps/s  "
            f"{free / cartpole:.3f}x CartPole at most"
        )
    from sb3_pm.machine import usable_cores

    cores = usable_cores()
    updates = phases.get("train()", 0.0) + phases.get("estimator fit", 0.0)
    if updates > 0 and updates_on_cpu:
        seconds = updates / cores  # for this run's agent-steps
        budget = seconds * agents * 50_000 / agent_steps
        print(
            f"    {f'bound: updates alone on {cores} cores':<44} {budget / 60:7.1f} min for the paper "
            f"budget at least ({agent_steps / seconds / cartpole:.3f}x CartPole at most)"
        )


def team_speed(
    graph: str,
    config: str,
    algo: str | None,
    timesteps: int,
    n_envs: int | None,
    n_steps: int | None,
    profile: bool = False,
    n_epochs: int | None = None,
    concurrent: bool = True,
    rollouts: str = "stacked",
    device: str = "cpu",
    attention_rule: str = "batch",
    n_agents: int = 4,
    update_slots: str = "auto",
    cartpole: float | None = None,
) -> float:
    """Agent-steps per second of one team after a one-rollout warm-up (with ``profile``, its phases
    and, given ``cartpole``'s steps per second, the bounds of the module docstring are printed)."""
    from sb3_pm.agents.training.team import IndependentPPO
    from sb3_pm.policies import attention
    from sb3_pm.zoo.config import load_config

    entry = load_config(config, graph)
    entry.n_agents = n_agents  # before team_kwargs(): per-agent learning rates follow the team size
    options = entry.team_kwargs()
    options["env_kwargs"] = {**options["env_kwargs"], "max_cycles": 500}
    if algo is not None:
        options["algo"], options["policy"] = algo, None
    if n_envs is not None:
        options["n_envs"] = n_envs
    if n_steps is not None:
        options["hyperparams"] = {**options["hyperparams"], "n_steps": n_steps, "batch_size": n_steps}
    if n_epochs is not None:
        options["hyperparams"] = {**options["hyperparams"], "n_epochs": n_epochs}
    if options["algo"] != "dcbf_ppo":  # policy_kwargs of the DCBF policy mean nothing to others
        options["hyperparams"].pop("policy_kwargs", None)
    rollout_device, _, update_device = device.partition("+")
    team = IndependentPPO(graph, seed=0, concurrent_updates=concurrent, device=rollout_device, **options)
    team.update_device = update_device or None
    team.batched_rollouts = rollouts == "stacked"
    slots = {"auto": None, "all": n_agents}
    team.update_slots = slots[update_slots] if update_slots in slots else int(update_slots)
    rollout = team.models[team.agents[0]].n_steps * team.n_envs
    default_batch_scores = attention.FUSED_MIN_BATCH_SCORES
    if attention_rule == "map":  # no batch is ever large enough: the per-map rule alone
        attention.FUSED_MIN_BATCH_SCORES = 2**62
    phases: dict[str, float] = defaultdict(float)
    undo = None
    try:
        team.learn(rollout)  # warm-up: one rollout and one train() per learner
        undo = _instrument(team, phases) if profile else None
        start = time.perf_counter()
        team.learn(timesteps, reset_num_timesteps=False)
    finally:
        attention.FUSED_MIN_BATCH_SCORES = default_batch_scores
        if undo is not None:
            undo()
    elapsed = time.perf_counter() - start
    if profile:
        if not concurrent:
            phases["rest (buffers, callbacks, hand-offs)"] = elapsed - sum(phases.values())
        for name, seconds in phases.items():
            print(f"    {name:<44} {seconds:7.2f} s  {100 * seconds / elapsed:5.1f}%")
    agent_steps = team.n_agents * (team.num_timesteps - rollout)
    if profile and cartpole is not None:
        on_cpu = "cuda" not in (update_device or rollout_device)
        print_bounds(phases, elapsed, agent_steps, cartpole, team.n_agents, updates_on_cpu=on_cpu)
    return agent_steps / elapsed


def cartpole_speed(timesteps: int) -> float:
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env

    env = make_vec_env("CartPole-v1", n_envs=8, seed=0)
    model = PPO("MlpPolicy", env, n_steps=256, batch_size=256, n_epochs=5, seed=0, device="cpu")
    model.learn(2048)
    start = time.perf_counter()
    model.learn(timesteps, reset_num_timesteps=False)
    return (model.num_timesteps - 2048) / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=1000, help="timed steps per learner (default 1000)")
    parser.add_argument(
        "--cartpole-timesteps", type=int, default=20480, help="timed CartPole steps (default 20480)"
    )
    parser.add_argument("--graphs", nargs="+", default=["paper-50", "paper-200"])
    parser.add_argument("--algo", default=None, help="dcbf_ppo | maskable_ppo | ppo (default: the config's)")
    parser.add_argument("--config", default="ippo", help="team config: a path or shipped name (default ippo)")
    parser.add_argument("--n-envs", type=int, default=None, help="override the config's n_envs")
    parser.add_argument("--n-steps", type=int, default=None, help="override n_steps (and batch_size)")
    parser.add_argument(
        "--n-epochs",
        type=int,
        nargs="+",
        default=[None],
        help="override n_epochs, the passes over each rollout (default: the config's; give several "
        "for the ratios)",
    )
    parser.add_argument("--threads", type=int, default=th.get_num_threads(), help="torch threads")
    parser.add_argument("--repeats", type=int, default=1, help="timed runs per graph (median printed)")
    parser.add_argument("--profile", action="store_true", help="print where each team's time goes")
    parser.add_argument(
        "--updates",
        nargs="+",
        choices=["side-by-side", "serial"],
        default=["side-by-side"],
        help="how the learners' update phases run (default side-by-side; give both to compare)",
    )
    parser.add_argument(
        "--rollouts",
        nargs="+",
        choices=["stacked", "serial"],
        default=["stacked"],
        help="how the learners' rollout passes run (default stacked; give both to compare)",
    )
    parser.add_argument(
        "--devices",
        nargs="+",
        default=["cpu"],
        choices=["cpu", "cuda", "cpu+cuda"],
        help="torch devices of the team's learners; cpu+cuda: rollouts on the CPU, updates on the GPU "
        "(default cpu; give several for the ratios)",
    )
    parser.add_argument(
        "--attention",
        nargs="+",
        choices=["batch", "map"],
        default=["batch"],
        help="when the dense attention runs the chunked kernel: batch (the default) or map (the "
        "previous, per-map rule); give both for the ratio",
    )
    parser.add_argument("--agents", type=int, default=4, help="agents of the team (default 4)")
    parser.add_argument(
        "--update-slots",
        nargs="+",
        default=["auto"],
        help="learners updating at once: auto (the default, one per core), all, or a number; "
        "give several for the ratios",
    )
    args = parser.parse_args()
    if any("cuda" in device for device in args.devices) and not th.cuda.is_available():
        parser.error("--devices cuda: torch sees no CUDA device here")
    for slots in args.update_slots:
        if slots not in ("auto", "all") and not (slots.isdigit() and int(slots) > 0):
            parser.error(f"--update-slots: auto, all or a positive number, got {slots!r}")
    th.set_num_threads(args.threads)
    print(
        f"torch threads: {args.threads}; team: {args.agents} agents, config {args.config}"
        + (f", algo {args.algo}" if args.algo else "")
        + (f", n_envs={args.n_envs}" if args.n_envs else "")
        + (f", n_steps={args.n_steps}" if args.n_steps else "")
        + f"; load average {os.getloadavg()[0]:.2f}"
    )
    cartpole = cartpole_speed(args.cartpole_timesteps)
    print(f"{'SB3 PPO MlpPolicy CartPole-v1, 8 envs':<74} {cartpole:>10.0f} steps/s")
    for graph in args.graphs:
        combinations = itertools.product(
            args.devices,
            args.updates,
            args.rollouts,
            args.attention,
            args.update_slots,
            args.n_epochs,
        )
        for device, mode, rollouts, attention_rule, slots, epochs in combinations:
            runs = [
                team_speed(
                    graph,
                    args.config,
                    args.algo,
                    args.timesteps,
                    args.n_envs,
                    args.n_steps,
                    args.profile,
                    n_epochs=epochs,
                    concurrent=mode == "side-by-side",
                    rollouts=rollouts,
                    device=device,
                    attention_rule=attention_rule,
                    n_agents=args.agents,
                    update_slots=slots,
                    cartpole=cartpole,
                )
                for _ in range(args.repeats)
            ]
            speed = statistics.median(runs)
            paper = args.agents * 50_000 / speed
            spread = f"  (runs: {', '.join(f'{r:.0f}' for r in runs)})" if len(runs) > 1 else ""
            where = "" if args.devices == ["cpu"] else f", {device}"
            # a team on a GPU updates one learner after another, whatever --updates asked
            updates = "serial" if device == "cuda" else mode
            rule = "" if args.attention == ["batch"] else f", attention {attention_rule}"
            rule += "" if args.update_slots == ["auto"] else f", update slots {slots}"
            rule += "" if epochs is None else f", n_epochs {epochs}"
            options = f"{args.algo or 'config'}, {updates}, {rollouts}{where}{rule}"
            label = f"team {graph} ({options})"
            print(
                f"{label:<74} {speed:>10.0f} agent-steps/s   {speed / cartpole:.3f}x CartPole   "
                f"paper budget ({args.agents} x 50,000): {paper / 60:.1f} min{spread}"
            )


if __name__ == "__main__":
    main()
