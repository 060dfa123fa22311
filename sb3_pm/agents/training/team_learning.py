"""A team's training run: every learner's own SB3 ``learn()``, stepped together.

:func:`run_team_learning` is the body of
:meth:`IndependentPPO.learn <sb3_pm.agents.training.team.IndependentPPO.learn>`: it seeds each
learner's random stream, builds its callbacks, attaches the batched rollout pass, runs the learners
in their threads through the team's multiplexer (:mod:`sb3_pm.agents.multiplexing`) and takes
checkpoints at the rollout barriers (:mod:`sb3_pm.agents.training.checkpoints`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from stable_baselines3.common.utils import set_random_seed

from sb3_pm.agents.multiplexing.learner_threads import learn_concurrently, raise_first_error
from sb3_pm.agents.multiplexing.streams import capture_stream, learner_streams, load_stream
from sb3_pm.agents.multiplexing.update_slots import UpdateSlots, default_update_slots
from sb3_pm.agents.training.checkpoints import CheckpointSchedule, TrainingInterrupted, checkpoint_at_barrier
from sb3_pm.agents.training.learner_callbacks import CallbackArg, learner_callbacks, per_agent_callbacks
from sb3_pm.agents.training.learners import learn_seed
from sb3_pm.agents.training.team_callbacks import TeamScalars, split_team_callbacks

logger = logging.getLogger(__name__)


def run_team_learning(
    team: Any,
    total_timesteps: int,
    callback: CallbackArg,
    progress_bar: bool,
    reset_num_timesteps: bool,
    log_interval: int,
    tb_log_name: str | None,
    checkpoints: CheckpointSchedule | None,
    on_interrupt: Callable[[], None] | None,
) -> Any:
    """:meth:`IndependentPPO.learn <sb3_pm.agents.training.team.IndependentPPO.learn>`'s body, run
    with the deploy filter off: every learner's own ``learn()`` in its own thread, stepped together
    through the team's multiplexer, each drawing from its own random stream. Returns ``team``."""
    # Read at every learn() (torch's thread count may have changed since construction), and
    # before anything changes, so that a bad count changes nothing.
    count = team.update_slots if team.update_slots is not None else default_update_slots()
    slots: UpdateSlots | None = UpdateSlots(count)  # checks the count even without side by side
    if not team.hub.concurrent_updates:
        slots = None
    if not reset_num_timesteps and any(m._last_obs is None for m in team.models.values()):
        # All learners must reset together (the multiplexer steps them as one).
        for model in team.models.values():
            model._last_obs = None
    # Whatever ran since construction (another team, an evaluation) must not leak into this
    # run: with the baton, each learner draws from its own stream, seeded here, so the run is a
    # function of (seed, num_timesteps, parameters) alone. Without it, a shared reseed.
    caller_stream = capture_stream()
    if team.hub.strict_order:
        resume = None if reset_num_timesteps else team._resume_streams
        team.hub.set_streams(resume or learner_streams(team.seed, team.num_timesteps, team.n_agents))
        team._resume_streams = None
    else:
        team.hub.set_streams(None)
        set_random_seed(learn_seed(team.seed, team.num_timesteps))
    learner_side, team_callbacks = split_team_callbacks(callback)
    user_callbacks = per_agent_callbacks(learner_side, team.agents)
    team_logger = team.team_logger(tb_log_name)
    if team_logger.output_formats and not any(isinstance(c, TeamScalars) for c in team_callbacks):
        team_callbacks = [TeamScalars(), *team_callbacks]  # the team's scalars beside the agents' runs
    for team_callback in team_callbacks:
        team_callback.init_callback(team, team_logger)
    learn_kwargs = []
    for agent, user in zip(team.agents, user_callbacks):
        learn_kwargs.append(
            {
                "total_timesteps": int(total_timesteps),
                "callback": learner_callbacks(team.models[agent], user),
                "log_interval": log_interval,
                "tb_log_name": f"{tb_log_name or ''}{agent}",
                "reset_num_timesteps": reset_num_timesteps,
                "progress_bar": False,
            }
        )
    bar = None
    if progress_bar:
        from sb3_pm.progress import progress_bar as make_progress

        rollout = team.models[team.agents[0]].n_steps * team.n_envs
        rollouts = -(-int(total_timesteps) // rollout)
        bar = make_progress(
            rollouts * rollout * team.n_agents, f"{team.algo} x{team.n_agents}", unit="agent-step"
        )
        team.hub.on_round = bar.update
    def on_sync() -> str | None:
        reason = checkpoint_at_barrier(team, checkpoints)
        for team_callback in team_callbacks:
            team_callback.on_barrier()
        return reason

    team.hub.on_sync = on_sync
    batcher = team._rollout_batcher()
    if batcher is not None:
        batcher.attach()
    team.hub.update_slots = slots
    errors: list[BaseException | None] = [KeyboardInterrupt()]  # until the learners return
    try:
        errors = learn_concurrently(
            [team.models[a] for a in team.agents],
            team.hub,
            learn_kwargs,
            graceful_interrupt=checkpoints is not None,
            on_interrupt=on_interrupt,
        )
    except KeyboardInterrupt:
        if checkpoints is not None and team.hub.stopped is not None and checkpoints.last is not None:
            raise TrainingInterrupted(checkpoints.last) from None
        raise
    finally:
        if batcher is not None:
            batcher.detach()
        team.hub.on_round = None
        team.hub.on_sync = None
        load_stream(caller_stream)
        if bar is not None:
            bar.close()
        failed = any(error is not None for error in errors)
        if team_logger is not team._custom_logger and failed:  # else closed below, once written to
            team_logger.close()
    if not failed:
        for team_callback in team_callbacks:
            team_callback.on_training_end()
        if team_logger is not team._custom_logger:
            team_logger.close()
    raise_first_error(errors)
    if team.hub.aborted is not None:
        logger.warning("team training ended early: %s", team.hub.aborted)
    return team


__all__ = ["run_team_learning"]
