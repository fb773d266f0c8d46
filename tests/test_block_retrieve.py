"""The scripted retrieve (``tasks/scripted/block_retrieve_script.py``): its rules on constructed observations (grip,
lift, transfer over the near wall, lower, release, done, give up), the action a function of the observation and the
step only, its binding to the target block, the retrieve pick order, a real episode of the retrieve stage
(``tasks/retrieve.py``) that takes a block out of the pile and sets it down on the staging area, the scripted stage's
policy system, and ``experiments/retrieve_chain.py``'s short run and bad input."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.modeling.blocks import BLOCK_SPECS, TOTAL_HEIGHT
from seqdex_drake.observation_layout import OBJECT_POSE, PALM_POSE
from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q, unscale_limits_to_action
from seqdex_drake.scene.piles import BOX_CENTER
from seqdex_drake.tasks.blocks_common import STAGING_HIGH, STAGING_LOW, retrieve_order
from seqdex_drake.tasks.scripted.block_grasp_script import CLOSING, p_PalmC_Palm
from seqdex_drake.tasks.scripted.block_retrieve_script import ScriptedBlockRetrieve, block_geometry, on_staging_area

REPO = Path(__file__).resolve().parents[1]
LENGTH = BLOCK_SPECS[5].footprint[0]
STAGE = (STAGING_LOW + STAGING_HIGH) / 2
TABLE = BOX_CENTER[2]


def observation(C, centre, upright=True) -> np.ndarray:
    """An observation with the grasp centre at ``C`` (palm frame = world) and the block's centre at ``centre``,
    upright or lying on a long side (its z axis along world y)."""
    o = np.zeros(160)
    o[PALM_POSE] = np.r_[np.asarray(C) - p_PalmC_Palm, 1.0, 0.0, 0.0, 0.0]
    if upright:
        o[OBJECT_POSE] = np.r_[np.asarray(centre) - [0.0, 0.0, TOTAL_HEIGHT / 2], 1.0, 0.0, 0.0, 0.0]
    else:  # Rolled -90 deg about x: the body z axis along world +y.
        o[OBJECT_POSE] = np.r_[np.asarray(centre) - [0.0, TOTAL_HEIGHT / 2, 0.0], np.cos(-np.pi / 4),
                               np.sin(-np.pi / 4), 0.0, 0.0]
    return o


def resting(xy, upright=True) -> np.ndarray:
    """A block centre resting on the table (or box floor) at ``xy``."""
    return np.r_[xy, TABLE + (TOTAL_HEIGHT / 2 if upright else 0.015)]


def test_geometry_finds_the_centre_and_the_lowest_point_of_a_lying_block():
    centre = resting([0.2, 0.2], upright=False)
    found, bottom = block_geometry(observation(centre + [0, 0, 0.2], centre, upright=False), LENGTH)
    assert np.allclose(found, centre, atol=1e-9)
    assert bottom == pytest.approx(TABLE, abs=1e-9)  # Lying on a long side: 3 cm tall, its centre 1.5 cm up.


def test_rules_from_the_pile_to_the_staging_area():
    script = ScriptedBlockRetrieve(length=LENGTH)
    in_box = resting([0.25, 0.2])
    # The first steps of a window grip; a pinch that did not take (the block stays as C rises) lets go.
    assert script.phase(observation(in_box + [0, 0, 0.1], in_box), 10) == "grip"
    assert script.phase(observation(in_box + [0, 0, 0.1], in_box), 60) == "regrip"
    assert script.phase(observation(in_box, in_box), 60) == "lift"
    # Held above the walls: carried over the near (-y) wall first, then toward the staging point.
    high = np.r_[0.25, 0.2, 0.85]
    assert script.phase(observation(high, high), 60) == "transfer"
    assert script.act(observation(high, high), 60)[17] < 0 and script.act(observation(high, high), 60)[18] >= 0
    outside = np.r_[0.25, -0.12, 0.86]
    action = script.act(observation(outside, outside), 210)
    assert script.phase(observation(outside, outside), 210) == "transfer"
    assert action[16] < 0 and action[17] < 0  # Toward the staging point, at (-0.025, -0.30).
    # Over the staging point: lowered, then let go on the table: the hand goes back to the pre-grasp jaws.
    above = np.r_[STAGE, 0.80]
    assert script.phase(observation(above, above), 250) == "lower"
    assert script.act(observation(above, above), 250)[18] < 0
    on_table = resting(STAGE)
    assert script.phase(observation(on_table, on_table), 260) == "release"
    assert np.allclose(script.act(observation(on_table, on_table), 260)[:16], unscale_limits_to_action(CLOSING[0]))
    # Out of the hand on the staging area: done (whatever the step); elsewhere after the attempts: given up.
    assert on_staging_area(on_table)
    assert script.phase(observation(on_table + [0, 0, 0.05], on_table), 290) == "rise"
    assert script.act(observation(on_table + [0, 0, 0.05], on_table), 290)[18] > 0
    assert script.phase(observation(np.r_[STAGE, 0.87], on_table), 290) == "done"
    assert np.allclose(script.act(observation(np.r_[STAGE, 0.87], on_table), 290)[:16],
                       unscale_limits_to_action(ALLEGRO_OPEN_Q))  # Fingers straight, as Search leaves them.
    assert script.phase(observation(in_box + [0, 0, 0.2], in_box), 3 * 100 + 5) == "give_up"
    dropped = resting([0.2, -0.12], upright=False)  # Fell beside the box in the carry: gripped again.
    assert script.phase(observation(dropped + [0, 0, 0.2], dropped, upright=False), 3 * 100 + 5) == "grip"


def test_a_block_held_off_centre_is_carried_until_it_clears_the_near_wall():
    """The carry's first leg takes the block over the near wall (``over_y``); a block hanging 2 cm behind C (a lying
    block pinched near one end) never gets there while C stops at ``over_y``: once C is there the carry goes on
    toward the staging point (the old rule held C at ``over_y`` until the block fell out of the hand)."""
    script = ScriptedBlockRetrieve(length=LENGTH)
    C = np.r_[0.25, script.over_y, script.carry_z]
    centre = C + [0.0, 0.02, 0.0]  # C on the block's long axis (held), the centre 2 cm behind it.
    o = observation(C, centre, upright=False)
    assert script.phase(o, 200) == "transfer"
    assert script.act(o, 200)[17] < -0.1  # Still toward -y, not stalled at C = over_y.


def test_the_action_is_a_function_of_the_observation_and_the_step_only():
    o = observation(np.r_[0.25, 0.2, 0.75], resting([0.26, 0.21], upright=False), upright=False)
    first = [ScriptedBlockRetrieve(length=LENGTH).act(o, step) for step in (0, 20, 60, 150)]
    script = ScriptedBlockRetrieve(length=LENGTH)
    for step in (150, 60, 20, 0):  # Another instance, other order: the same actions.
        assert np.array_equal(script.act(o, step), first[(0, 20, 60, 150).index(step)])
    assert all(np.all(np.abs(a) <= 1.0) and a.shape == (19,) for a in first)


@pytest.mark.parametrize("kwargs, message", [
    ({"length": 0.0}, "length must be the block's length in metres"),
    ({"length": LENGTH, "attempt_steps": 50}, "attempt_steps \\(50\\) must leave the pinch"),
])
def test_bad_parameters_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ScriptedBlockRetrieve(**kwargs)


def test_retrieve_order_takes_uncovered_blocks_off_the_floor_highest_first():
    up = [1.0, 0.0, 0.0, 0.0]
    q = np.array([up + [0.20, 0.20, TABLE],            # 0: on the floor
                  up + [0.20, 0.20, TABLE + 0.04],     # 1: on block 0, covered by block 2
                  up + [0.21, 0.20, TABLE + 0.08],     # 2: on top
                  up + [0.30, 0.10, TABLE + 0.04]])    # 3: on something, uncovered, lower than 2
    assert retrieve_order(q, [0, 1, 2, 3]) == [2, 3, 1, 0]


def test_the_retrieve_binds_to_its_target_block_and_refuses_to_act_without_one():
    o = observation(np.r_[0.25, 0.2, 0.75], resting([0.26, 0.21]))
    with pytest.raises(ValueError, match="no target block: bind it with for_object"):
        ScriptedBlockRetrieve().act(o, 0)
    bound = ScriptedBlockRetrieve().for_object("block_5_3")
    assert bound.length == LENGTH and np.array_equal(bound.act(o, 7), ScriptedBlockRetrieve(length=LENGTH).act(o, 7))
    with pytest.raises(ValueError, match="takes a pile block"):
        ScriptedBlockRetrieve().for_object("hammer")


def test_the_retrieve_stage_takes_its_target_out_of_the_pile_and_sets_it_down_on_the_staging_area():
    """The scripted stage's env (``tasks/retrieve.py``): the pile, its target bound into the base, zero corrections;
    it succeeds only once the block rests on the staging area out of the hand."""
    env = make_env("retrieve")
    observation_, info = env.reset(seed=0)
    assert not info["success"] and np.all(np.abs(env.object_position()[:2] - BOX_CENTER[:2]) < 0.3)
    script, phases = ScriptedBlockRetrieve().for_object(env.target_object), []
    for step in range(env.config.episode_length):
        phases.append(script.phase(observation_, step))
        if script.finished(observation_, step):
            break
        observation_, _, terminated, truncated, info = env.step(np.zeros(19))
        assert not terminated and not info["simulator_error"]
    assert phases[-1] == "done", f"ended in {phases[-1]} after {len(phases)} steps"
    assert {"grip", "lift", "transfer", "lower", "release", "rise"} <= set(phases)
    assert info["success"] and on_staging_area(env.object_position())


def test_a_scripted_stage_system_acts_as_its_bound_script_and_says_when_it_is_finished():
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from seqdex_drake.controller.policy import PolicyParams, PolicySystem

    script = ScriptedBlockRetrieve(length=LENGTH)
    done = resting(STAGE, upright=False)
    o = observation(np.r_[done[:2], script.carry_z], done, upright=False)[:159]
    assert script.finished(o, 400)

    def run(active: float, target: int | None) -> tuple[np.ndarray, float]:
        system = PolicySystem.scripted(159, PolicyParams(ema=1.0, residual="block_retrieve_script"),
                                       body_names=["world", "block_5_3"])
        builder = DiagramBuilder()
        builder.AddSystem(system)
        for port, value in (("observation", o), ("active", [active])):
            builder.Connect(builder.AddSystem(ConstantVectorSource(np.asarray(value, float))).get_output_port(),
                            system.GetInputPort(port))
        simulator = Simulator(builder.Build())
        context = system.GetMyMutableContextFromRoot(simulator.get_mutable_context())
        if target is not None:
            system.set_target_body(context, target)
        simulator.AdvanceTo(1.5 / 60.0)  # Two updates (t = 0, 1/60).
        return system.GetOutputPort("raw_action").Eval(context), system.GetOutputPort("finished").Eval(context)[0]

    raw, finished = run(1.0, 1)
    assert system_is_the_script(raw, script.act(o, 1)) and finished == 1.0
    assert run(0.0, 1)[1] == 0.0  # An inactive stage never says finished (the next stage must not end with it).
    with pytest.raises(Exception, match="no target block"):
        run(1.0, None)
    with pytest.raises(ValueError, match="body index 5 is not a body"):
        run(1.0, 5)


def system_is_the_script(raw: np.ndarray, action: np.ndarray) -> bool:
    return raw.shape == (19,) and np.allclose(raw, np.clip(action, -1.0, 1.0), atol=1e-12)


def retrieve_chain(*args, timeout=300):
    return subprocess.run([sys.executable, str(REPO / "experiments" / "retrieve_chain.py"), *args],
                          capture_output=True, text=True, timeout=timeout, cwd=REPO)


def test_retrieve_chain_short_run_writes_its_episodes_alike_whatever_ran_before_and_refuses_bad_input(tmp_path):
    after, alone = tmp_path / "after.json", tmp_path / "alone.json"
    result = retrieve_chain("--test", "--episodes", "0-1", "--out", str(after))
    assert result.returncode == 0, result.stderr[-2000:]
    rows = json.loads(after.read_text())["per_episode"]
    assert [row["episode"] for row in rows] == [0, 1] and [row["block_type"] for row in rows] == [1, 2]
    assert rows[0]["block"].startswith("block_1_") and rows[0]["retrieve_steps"] == 29
    assert rows[0]["retrieve_phase"] == "grip" and not rows[0]["staged"]  # 30 steps: still gripping.
    summary = retrieve_chain("--summary", str(after))
    assert json.loads(summary.stdout)["episodes"] == 2 and json.loads(summary.stdout)["staged"] == 0
    # An episode's record does not depend on the episodes run before it in the same process.
    assert retrieve_chain("--test", "--episodes", "1", "--out", str(alone)).returncode == 0
    first = json.loads(alone.read_text())["per_episode"][0]
    assert {**rows[1], "wall_s": 0} == {**first, "wall_s": 0}
    # --retrieve-only: the retrieve alone, its own step budget, no chain after it (no funnel keys).
    only = tmp_path / "only.json"
    assert retrieve_chain("--retrieve-only", "--retrieve-steps", "30", "--episodes", "1", "--out",
                          str(only)).returncode == 0
    record = json.loads(only.read_text())["per_episode"][0]
    assert {**record, "wall_s": 0} == {**first, "wall_s": 0} and "placed" not in record
    bad = retrieve_chain("--episodes", "5-2")
    assert bad.returncode == 2 and "--episodes must be A-B" in bad.stderr and "Traceback" not in bad.stderr


def test_a_retrieve_that_leaves_its_block_in_the_pile_fetches_the_next_block_of_its_type_on_the_same_clock():
    """``evaluation/refetch.py`` in the whole chain: a 3-tick retrieve budget cannot take the block out, so the
    runner fetches the next block of the type (the chain restarts on it, the episode's clock running on), at most
    ``refetches`` times; the watch never fires without a retrieve stage, and a negative cap is refused. The target
    block counts as lifted (no switch back to a stage before Insert) only when it is off the table in hand."""
    from seqdex_drake.evaluation.refetch import RetrieveWatch
    from seqdex_drake.evaluation.runner import ChainRunError, ChainRunner, RunConfig
    from seqdex_drake.manual import LoadManual, goal_vector

    runner = ChainRunner(RunConfig(family="building_blocks", run_dir=str(REPO / "checkpoints" / "building_blocks"),
                                   max_switches=0, seed=3, stage_steps=(1, 3, 1, 1, 1), refetches=1))
    step = LoadManual("small_wall").steps[0]
    first = runner.start_block(step.block_type, goal_vector(step))
    targets, times = [], []

    def watch(r: ChainRunner) -> bool:
        if not targets or targets[-1] != r.target:
            targets.append(r.target)
            times.append(r.context.get_time())
        return r.context.get_time() < 6.0

    outcome = runner.run(runner.episode_limit(), on_tick=watch)
    assert outcome.refetches == 1 == runner.refetches and len(targets) == 2 and targets[0] == first
    assert targets[1] != first and targets[1].startswith(f"block_{step.block_type}_")
    assert times[1] > 1.0 and outcome.time >= 6.0  # One clock: the refetch did not restart the episode's time.
    third = runner.start_block(step.block_type, goal_vector(step))
    assert third not in targets and runner.refetches == 0
    # Only Insert may follow a block lifted in hand (FREE_OBJECT_STAGES): the block on the table is free, 0.5 m up
    # (as Grasp lifts it) it is held.
    from pydrake.math import RigidTransform

    approach = runner.controller.GetSubsystemByName("approach_target")

    def lifted() -> bool:
        return bool(approach.GetOutputPort("object_lifted").Eval(approach.GetMyContextFromRoot(runner.context))[0])

    for z, held in ((0.6, False), (1.1, True)):
        runner.objects.set_pose(runner.context, third, RigidTransform([-0.025, -0.30, z]), frozen=False)
        assert lifted() == held
    assert RetrieveWatch(["search", "orient"], 2).stage is None
    assert not RetrieveWatch(["search", "orient"], 2).due(1, lambda: True)
    watch = RetrieveWatch(["search", "retrieve", "orient"], 2)
    assert not watch.due(1, lambda: True) and not watch.due(2, lambda: False)  # Left it with the block out: kept.
    assert not watch.due(1, lambda: True) and watch.due(2, lambda: True)  # Left it with the block in the box.
    with pytest.raises(ChainRunError, match="refetches must be >= 0"):
        ChainRunner(RunConfig(family="building_blocks", refetches=-1))
