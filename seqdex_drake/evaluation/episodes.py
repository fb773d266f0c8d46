"""One ``seqdex evaluate`` episode: the runner config every episode of an evaluation shares and the episode itself
(a tool from the table, or a block from a cached pile to a sampled goal), seeded by (seed, object, episode). Used by
:mod:`~seqdex_drake.evaluation.experiments` in this process and by :mod:`~seqdex_drake.evaluation.parallel`'s
workers."""

import numpy as np
from pydrake.math import RollPitchYaw

from seqdex_drake.evaluation.runner import ChainRunner, RunConfig
from seqdex_drake.manual import ManualStep, goal_vector
from seqdex_drake.modeling.blocks import BLOCK_SPECS

#: The transition whose feasibility scores the scatter shows (paper: Orient -> Grasp; tools: -> Reorient).
SCATTER_STAGE = {"building_blocks": "grasp", "tool_positioning": "tool_reorient"}


def run_config(config, **overrides) -> RunConfig:
    """The runner of every episode of ``config`` (an :class:`~seqdex_drake.evaluation.experiments.EvalConfig`):
    the first seed's (pile, untrained policies) whichever seed runs."""
    settings = dict(family=config.family, run_dir=config.run_dir, max_switches=config.max_switches,
                    stage_steps=config.stage_steps, seed=config.seeds[0],
                    untrained_hidden_sizes=config.untrained_hidden_sizes)
    settings.update(overrides)
    return RunConfig(**settings)


def run_episode(runner: ChainRunner, config, key, seed: int, episode: int,
                scatter: bool) -> tuple[dict, list, list]:
    """Runs one object's episode (seeded by ``seed, key, episode``): its result and, if ``scatter``, the object's
    roll-pitch-yaw and score at every tick the scatter transition's feasibility function scored.

    The runner's clock restarts at 0: the simulation's rounding depends on the absolute time, so without this an
    episode's outcome would depend on the episodes the runner ran before it (and on how seeds are split over
    workers)."""
    runner.context.SetTime(0.0)
    rng = np.random.default_rng([seed, int(key), episode])
    if config.family == "building_blocks":
        runner.restore_pile(int(rng.integers(1 << 30)))
        runner.start_block(int(key), sample_goal(int(key), rng), reset_robot=True)
    else:
        runner.start_tool(int(key), rng)
    stage = runner.tasks.index(SCATTER_STAGE[config.family])
    rpy, scores = [], []

    def record(r: ChainRunner) -> bool:
        c = float(r.chain_output("feasibility_scores")[stage])
        if np.isfinite(c):
            rpy.append(RollPitchYaw(r.object_pose().rotation()).vector())
            scores.append(c)
        return True

    limit = config.time_limit or runner.episode_limit()
    outcome = runner.run(limit, on_tick=record if scatter else None)
    result = {"success": bool(outcome.success), "time": outcome.time, "switches": outcome.switches,
              "last_stage": outcome.last_stage, "position_error": outcome.position_error,
              "rotation_error": outcome.rotation_error, **({"simulator_error": outcome.simulator_error}
                                                           if outcome.simulator_error else {})}
    return result, rpy, scores


def sample_goal(block_type: int, rng: np.random.Generator) -> np.ndarray:
    """A stud-aligned goal on the baseplate within the arm's comfortable reach (cells i 3-8, j 8-11), yaw 0/90."""
    yaw = float(rng.choice([0.0, 90.0]))
    nx, ny = BLOCK_SPECS[block_type].cells
    span = (ny, nx) if yaw else (nx, ny)
    cell = [int(rng.integers(3, 9 - span[0] + 1)), int(rng.integers(8, 12 - span[1] + 1))]
    return goal_vector(ManualStep(block_type=block_type, cell=cell, level=0, yaw_deg=yaw))
