"""The stacked acting pass of a rollout step on ``paper-50``: its parts, and split between threads.

    python docs/results/speed_probes/acting_pass_parts.py

Builds the default team, trains one rollout, and on the last joint step's observations times
(milliseconds per call, one torch thread, the training filter as during a rollout): the whole
stacked pass for the four learners; its parts (the estimator, the DCBF filter, the GAT layers, and
the actor and critic heads, timed with the GAT layers and the layers' time taken off, and the
rest); and the pass split in two, learners 0-1 in this thread and 2-3 in a second one at the same
time (each half checked equal to the whole, bit for bit).
"""

import time
from concurrent.futures import ThreadPoolExecutor

import torch as th

import sb3_pm.agents.stacked_inference as stacked
from sb3_pm.agents.team import IndependentPPO
from sb3_pm.zoo import load_config

th.set_num_threads(1)
team = IndependentPPO.from_config(load_config("ippo", "paper-50"), "paper-50", seed=0)
team.learn(500)
team._training_filter()  # as during a rollout (learn() switched the deployment filter back on)
policies = [team.models[agent].policy for agent in team.agents]
published = [obs for obs in team.hub.published if isinstance(obs, dict)]  # the last joint step's
whole = stacked.StackedInference()
halves = (stacked.StackedInference(), stacked.StackedInference())
pool = ThreadPoolExecutor(1)


def milliseconds(function, calls: int = 300) -> float:
    for _ in range(10):
        function()
    start = time.perf_counter()
    for _ in range(calls):
        function()
    return (time.perf_counter() - start) / calls * 1e3


def second_half():
    with th.inference_mode():  # inference mode is per thread
        return halves[1].rollout_heads(policies[2:], published[2:])


def split():
    future = pool.submit(second_half)
    return halves[0].rollout_heads(policies[:2], published[:2]) + future.result()


with th.inference_mode():
    one, two = whole.rollout_heads(policies, published), split()
    assert one is not None and two is not None
    assert all(th.equal(a.logits, b.logits) and th.equal(a.values, b.values) for a, b in zip(one, two))
    stack = whole._stack
    maps = len(published[0]["nodes"])
    pre, u_hat, _, _ = whole._prepare(policies, published, maps)
    parts = {
        "whole pass": lambda: whole.rollout_heads(policies, published),
        "estimator": lambda: whole._uncertainty(stack, pre),
        "DCBF filter": lambda: stacked._filtered_masks(policies, pre, u_hat, None),
        "GAT layers": lambda: whole._embed(stack, pre),
        "GAT layers and heads": lambda: whole._heads_given(stack, pre, u_hat),
    }
    times = {name: milliseconds(function) for name, function in parts.items()}
    times["heads (actor, critic)"] = times["GAT layers and heads"] - times["GAT layers"]
    named = ("estimator", "DCBF filter", "GAT layers", "heads (actor, critic)")
    # the rest: checks, stacking the parameters, the observations' conversion, splitting the outputs
    times["rest"] = times["whole pass"] - sum(times[name] for name in named)
    for name in ("whole pass", *named, "rest"):
        print(f"{name:<24} {times[name]:6.2f} ms")
    for _ in range(3):
        print(
            f"whole {milliseconds(lambda: whole.rollout_heads(policies, published)):6.2f} ms, "
            f"split between two threads {milliseconds(split):6.2f} ms"
        )
pool.shutdown()
