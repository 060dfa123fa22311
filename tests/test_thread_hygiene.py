"""Acting runs with one torch thread unless told otherwise: evaluation and GIF recording."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch as th

from sb3_pm.baselines import make_team
from sb3_pm.evaluation import evaluate, record_gif


def counting_team() -> tuple[Any, list[int]]:
    """A baseline team whose ``predict_dict`` records torch's thread count."""
    team = make_team("random")
    seen: list[int] = []
    predict = team.predict_dict

    def recorded(*args: Any, **kwargs: Any) -> Any:
        seen.append(th.get_num_threads())
        return predict(*args, **kwargs)

    team.predict_dict = recorded  # type: ignore[method-assign]
    return team, seen


def test_gif_recording_and_evaluation_act_with_one_thread(tmp_path: Path) -> None:
    before = th.get_num_threads()
    th.set_num_threads(2)
    try:
        team, seen = counting_team()
        record_gif(team, "paper-50", tmp_path / "a.gif", n_agents=2, max_cycles=3)
        evaluate(team, "paper-50", n_agents=2, episodes=1, max_cycles=3)
        assert seen and set(seen) == {1}
        assert th.get_num_threads() == 2  # restored afterwards
        seen.clear()
        record_gif(team, "paper-50", tmp_path / "b.gif", n_agents=2, max_cycles=3, threads=None)
        assert set(seen) == {2}  # None leaves torch's count, so the check can fail
    finally:
        th.set_num_threads(before)
