"""One ``seqdex evaluate`` episode: the runner config every episode of an evaluation shares and the episode itself
(a tool from the table, or a block from a cached pile to a sampled goal), seeded by (seed, object, episode). Used by
:mod:`~seqdex_drake.evaluation.experiments` in this process and by :mod:`~seqdex_drake.evaluation.parallel`'s
workers."""

import numpy as np
from pydrake.math import RollPitchYaw

from seqdex_drake.evaluation.runner import ChainRunner, RunConfig
from seqdex_drake.manual import ManualStep, goal_vector
from seqdex_drake.modeling.blocks import BLOCK_SPECS

#: How far (m) above its start an object counts as lifted at a hand-over (in hand: Grasp lifts blocks 0.3 m).
HELD_LIFT = 0.1
#: The transition whose feasibility scores the scatter shows (paper: Orient -> Grasp; tools: -> Reorient).
SCATTER_STAGE = {"building_blocks": "grasp", "tool_positioning": "tool_reorient"}


def run_config(config, **overrides) -> RunConfig:
    """The runner of every episode of ``config`` (an :class:`~seqdex_drake.evaluation.experiments.EvalConfig`):
    the first seed's (pile, untrained policies) whichever seed runs."""
    settings = dict(family=config.family, run_dir=config.run_dir, max_switches=config.max_switches,
                    stage_steps=config.stage_steps, seed=config.seeds[0],
                    untrained_hidden_sizes=config.untrained_hidden_sizes, chain=getattr(config, "chain", ""),
                    trigger=getattr(config, "trigger", ""))
    settings.update(overrides)
    return RunConfig(**settings)


def current_score(runner: ChainRunner, stage: int) -> float:
    """c^stage on the switcher's history as it is now (after this tick's update), whatever its trigger computed
    this tick; NaN where the stage has no F or before its first observation. With the paper's timing the switcher
    computed the same value this tick; deciding only where a stage ends, it computed none."""
    switcher = runner.controller.GetSubsystemByName("switcher")
    if not switcher.has_feasibility(stage):
        return float("nan")
    history = switcher.history(switcher.GetMyContextFromRoot(runner.context), stage - 1)
    return float(switcher.score(stage, history)) if len(history) else float("nan")


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
        pile = runner.restore_pile(int(rng.integers(1 << 30)))
        yaws = runner.stage_configs[runner.tasks.index("insert")].goal_yaws_deg  # As Insert was trained.
        name = runner.start_block(int(key), sample_goal(int(key), rng, yaws), reset_robot=True)
        start = {"pile": pile, "block": name}  # Episodes with the same start differ only in their goal.
    else:
        start = {"tool": runner.start_tool(int(key), rng)}
    stage = runner.tasks.index(SCATTER_STAGE[config.family])
    rpy, scores = [], []
    start_height = runner.object_pose().translation()[2]
    entries: dict[str, list[float]] = {}  # Per stage, the object as the stage first started: [up_z, lift (m)].

    refetched = [0]

    def record(r: ChainRunner) -> bool:
        nonlocal start_height
        if r.refetches != refetched[0]:  # Another block of the type fetched: the funnel is the new block's.
            entries.clear()
            refetched[0], start_height = r.refetches, r.object_pose().translation()[2]
        entered = r.tasks[int(r.chain_output("active_stage")[0])]
        if entered not in entries:
            X = r.object_pose()
            entries[entered] = [float(X.rotation().matrix()[2, 2]), float(X.translation()[2] - start_height)]
        if scatter:
            c = current_score(r, stage)
            if np.isfinite(c):
                rpy.append(RollPitchYaw(r.object_pose().rotation()).vector())
                scores.append(c)
        return True

    limit = config.time_limit or runner.episode_limit()
    outcome = runner.run(limit, on_tick=record)
    result = {"success": bool(outcome.success), "time": outcome.time, "switches": outcome.switches,
              "last_stage": outcome.last_stage, "position_error": outcome.position_error,
              "rotation_error": outcome.rotation_error, "stage_entries": entries, "start": start,
              **({"simulator_error": outcome.simulator_error} if outcome.simulator_error else {}),
              **({"fell": True} if outcome.fell else {}),
              **({"refetches": outcome.refetches, "fetched": runner.target} if outcome.refetches else {})}
    return result, rpy, scores


def handover_notes(family: str, results: list[dict]) -> list[str]:
    """Where the episodes of a chain got to, from their ``stage_entries``: for Building Blocks, how many reached
    Grasp with the block upright (Orient's success: its z axis within acos(0.6) of world z) and Insert with it
    lifted at least ``HELD_LIFT`` (Grasp's); for Tool Positioning, how many reached Reorient with the tool lifted.
    For Building Blocks episodes that record their ``start``, also how many distinct (cached pile, block) starts
    they had: with few cached piles, episodes of one block type repeat a start. Then how many episodes ended with
    the object fallen off the table (``fell``) and how many in a failed simulation (``simulator_error``)."""
    checks = {"building_blocks": [("grasp", 0, 0.6, "upright when Grasp started"),
                                  ("insert", 1, HELD_LIFT, f"lifted >= {HELD_LIFT} m when Insert started")],
              "tool_positioning": [("tool_reorient", 1, HELD_LIFT, f"lifted >= {HELD_LIFT} m when Reorient "
                                                                    f"started")]}[family]
    notes = []
    for task, index, bound, what in checks:
        count = sum(1 for r in results if r.get("stage_entries", {}).get(task, [-np.inf] * 2)[index] > bound)
        notes.append(f"object {what}: {count} / {len(results)} episodes")
    starts = [r["start"] for r in results if "pile" in r.get("start", {})]
    if starts:  # A block type's episodes on one cached pile fetch the same block: fewer independent trials.
        distinct = len({(s["pile"], s["block"]) for s in starts})
        notes.append(f"distinct starts (cached pile, block): {distinct} in {len(starts)} episodes")
    fell = sum(1 for r in results if r.get("fell"))
    failed = sum(1 for r in results if r.get("simulator_error"))
    notes.append(f"object fell off the table: {fell} / {len(results)} episodes; simulation failed (diverged or "
                 f"a failed contact solve): {failed} / {len(results)}")
    return notes


def sample_goal(block_type: int, rng: np.random.Generator, yaws=(0.0, 90.0)) -> np.ndarray:
    """A stud-aligned goal on the baseplate within the arm's comfortable reach (cells i 3-8, j 8-11), at one of
    ``yaws`` (deg; the paper's 0 / 90, or those the chain's Insert policy was trained for,
    ``TaskConfig.goal_yaws_deg``: the budget variant's 90 only)."""
    yaw = float(rng.choice([float(y) for y in yaws]))
    nx, ny = BLOCK_SPECS[block_type].cells
    span = (ny, nx) if yaw else (nx, ny)
    cell = [int(rng.integers(3, 9 - span[0] + 1)), int(rng.integers(8, 12 - span[1] + 1))]
    return goal_vector(ManualStep(block_type=block_type, cell=cell, level=0, yaw_deg=yaw))
