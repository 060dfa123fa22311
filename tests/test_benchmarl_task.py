"""The monitoring env as a BenchMARL task (sb3_pm.integrations.benchmarl_task): a few frames of
MAPPO, then the trained policy as a team in the project's evaluation harness. Needs the extra
``benchmarl``."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

pytest.importorskip(
    "benchmarl", reason="BenchMARL is the optional extra 'benchmarl': pip install -e '.[benchmarl]'"
)

import torch  # noqa: E402

from sb3_pm.errors import InputError  # noqa: E402
from sb3_pm.evaluation import evaluate  # noqa: E402
from sb3_pm.integrations.benchmarl_task import (  # noqa: E402
    GROUP,
    BenchMARLTeam,
    MonitoringTaskClass,
    experiment_config,
    make_experiment,
    monitoring_task,
)

pytestmark = pytest.mark.slow


def test_the_task_takes_the_training_config_env_and_pickles() -> None:
    task = monitoring_task("paper-50", n_agents=4, max_cycles=40)
    assert task.config["reward"] == {"clearing": 0.04, "territory": 0.04, "collision": 0.001}
    assert task.config["graph_knowledge"] == "known" and task.config["max_cycles"] == 40
    copy = pickle.loads(pickle.dumps(task))
    assert isinstance(copy, MonitoringTaskClass) and copy.config == task.config
    env = pickle.loads(pickle.dumps(task.get_env_fun(1, False, 0, "cpu")))()
    assert task.group_map(env) == {GROUP: [f"agent_{i}" for i in range(4)]}
    assert set(task.action_mask_spec(env)[GROUP].keys()) == {"action_mask"}
    rollout = env.rollout(40)  # random actions drawn from the masked action spec
    assert rollout["next", "done"][-1].all() and not rollout["next", "done"][:-1].any()
    env.close()


def test_failures_reach_torchrl_through_the_alive_mask() -> None:
    task = monitoring_task("paper-50", n_agents=4, max_cycles=20, failures={"agent_2": 5})
    env = task.get_env_fun(1, False, 0, "cpu")()
    rollout = env.rollout(20)
    alive = rollout["next", GROUP, "mask"]
    assert alive[:4].all() and not alive[4:19, 2].any() and alive[4:19][:, [0, 1, 3]].all()
    assert not alive[19].any()  # the episode is over: nobody acts
    assert rollout["next", "done"][-1].all() and not rollout["next", "done"][:-1].any()
    env.close()


def test_mappo_trains_a_few_frames_and_acts_legally_in_the_harness(tmp_path) -> None:
    torch.set_num_threads(1)
    task = monitoring_task("paper-50", n_agents=4)
    experiment = make_experiment("mappo", task, seed=0, frames=1000, lr=3e-4, folder=str(tmp_path))
    experiment.run()
    torch.set_num_threads(1)
    assert experiment.total_frames == 1000
    team = BenchMARLTeam.from_experiment(experiment, task, name="mappo")
    env = team.make_env("paper-50", max_cycles=60)  # raises on an illegal move (illegal_action="raise")
    observations, _ = env.reset(seed=7)
    team.reset(env, seed=1)
    while env.agents:
        actions = team.predict_dict(observations, deterministic=True)
        assert all(observations[agent]["action_mask"][action] for agent, action in actions.items())
        observations, *_ = env.step(actions)
    result = evaluate(team, "paper-50", episodes=1, seed=7, max_cycles=60)
    assert (
        np.isfinite(result.mean["avg_uncertainty"])
        and result.config["env_kwargs"]["graph_knowledge"] == "known"
    )


def test_bad_input_is_one_line_errors(tmp_path) -> None:
    with pytest.raises(InputError, match="n_agents"):
        monitoring_task("paper-50", n_agents=0)
    with pytest.raises(InputError, match="multiple of 500"):
        experiment_config(frames=700, lr=3e-4, folder=str(tmp_path))
    with pytest.raises(InputError, match="unknown algorithm"):
        make_experiment("ppo", monitoring_task("paper-50"), seed=0, frames=500, lr=3e-4, folder=str(tmp_path))
