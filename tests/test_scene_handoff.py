"""Hand-offs across station scenes (``envs/scene_handoff.py``): a Search state (the 72-block pile) starts Orient
(one block in the box) with the robot and the dug-out block where they were and the other blocks parked; a block
held at Grasp's end stays in hand when Insert (the boards scene) starts from it, carried over its goal; a state
without the carried fields is refused with a clear error; and chains check that every object has a counterpart in
the next scene."""

import dataclasses

import numpy as np
import pytest

from seqdex_drake.env_state import SceneHandoffError, check_handoff, counterpart
from seqdex_drake.envs.chain_env import ChainEnv
from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.tasks.carry import CARRY_HEIGHT
from seqdex_drake.tasks.insert import BASEPLATE_TOP, LAYER_HEIGHT, PLATE_XY
from seqdex_drake.tasks.registry import budget_config
from seqdex_drake.tasks.scripted.block_insert_script import ScriptedBlockInsert


@pytest.fixture(scope="module")
def envs():
    return {"search": make_env("search"), "orient": make_env("orient"),
            "grasp": make_env("grasp", budget_config("grasp")), "insert": make_env("insert")}


def test_search_state_starts_orient_with_its_block_and_robot(envs):
    search, orient = envs["search"], envs["orient"]
    search.reset(seed=3)
    search.step(np.zeros(19))
    state = search.get_state()
    assert state.robot_positions.shape == (23,) and state.target_positions.shape == (7,)
    orient.reset(seed=0)  # Whatever it held before.
    orient.reset(options={"initial_state": state})
    block_type = state.target_object.split("_")[1]
    assert orient.target_object == f"block_{block_type}"
    np.testing.assert_allclose(orient.object_position(), search.object_position(), atol=1e-12)
    np.testing.assert_allclose(np.r_[orient.arm_q(), orient.hand_q()], np.r_[search.arm_q(), search.hand_q()])
    np.testing.assert_allclose(orient.observation()[:143], search.observation()[:143], atol=1e-5)  # Up to tactile.
    others = [name for name in orient.objects.names if name != orient.target_object]
    positions = orient.objects.positions(orient.context)
    for name in others:  # Parked off the table, frozen.
        assert positions[orient.objects.index(name), 4] < -1.0
    assert orient.objects.frozen_names(orient.context) == others
    assert orient.context.get_time() == pytest.approx(search.context.get_time())
    for _ in range(3):
        *_, info = orient.step(np.zeros(19))
        assert not info.get("simulator_error")


def test_a_block_held_at_grasps_end_stays_in_hand_in_insert(envs):
    grasp, insert = envs["grasp"], envs["insert"]
    grasp.reset(seed=4)
    for _ in range(grasp.config.episode_length):
        *_, info = grasp.step(np.zeros(19))  # The scripted pickup (the residual at zero).
    assert info["success"]
    state = grasp.get_state()
    insert.reset(options={"initial_state": state})
    assert insert.target_object == grasp.target_object and insert.objects.frozen_names(insert.context) == [
        name for name in insert.objects.names if name != insert.target_object]
    # Insert draws its plate and goal as a reset does (the Grasp state has none).
    plates = [name for name in insert.objects.names if name.startswith("plate_")
              and insert.objects.positions(insert.context)[insert.objects.index(name), 4] > 0.0]
    assert len(plates) == 1 and insert.goal[2] == pytest.approx(BASEPLATE_TOP + int(plates[0][-1]) * LAYER_HEIGHT)
    assert np.linalg.norm(insert.goal[:2] - PLATE_XY) < 0.06
    # Carried, in hand, 3 cm over its goal and turned to the goal's orientation (the whole chain's carry).
    X_WG = insert.goal
    np.testing.assert_allclose(insert.object_pose().translation(), X_WG[:3] + [0.0, 0.0, CARRY_HEIGHT], atol=2e-4)
    assert insert.task.goal_errors(insert)[1] < 1e-3
    assert ScriptedBlockInsert().release_kind(insert.observation()) == "relax"  # Grasp's jaw pinch, not the tripod.
    turned = (insert.R_WP_hold.inverse() @ insert.R_WP_home).ToAngleAxis().angle()
    hold = np.r_[state.previous_action[:16], 0.0, 0.0, 0.0]  # The same hand targets; the wrist still.
    start = insert.object_position()
    for _ in range(30):
        insert.step(hold)
    assert np.linalg.norm(insert.object_position() - start) < 0.01  # Still in hand, where the carry left it.
    assert insert.task.goal_errors(insert)[1] < 0.05
    carried, R_held = insert.get_state(), insert.R_WP_hold
    insert.reset(seed=0)  # A reset of its own holds the palm as usual again.
    assert turned > 0.01 and insert.R_WP_hold is insert.R_WP_home
    insert.reset(options={"initial_state": insert.get_state()})  # A standalone state of its own: home, exactly.
    assert insert.R_WP_hold is insert.R_WP_home
    insert.reset(options={"initial_state": carried})  # A carried one: the turned palm, as it was held.
    assert (insert.R_WP_hold.inverse() @ R_held).ToAngleAxis().angle() < 0.01


def test_a_block_the_hand_does_not_hold_is_not_carried_to_its_goal(envs):
    """Early in Grasp the open hand hovers over the block, near enough to count as in hand by distance alone;
    Insert from that state must leave the block where it lies, not set it over its goal with the palm."""
    grasp, insert = envs["grasp"], envs["insert"]
    grasp.reset(seed=4)
    grasp.step(np.zeros(19))
    state = grasp.get_state()
    assert grasp.objects.robot_bodies_touching(grasp.plant_context, grasp.target_object) == 0
    insert.reset(options={"initial_state": state})
    np.testing.assert_allclose(insert.object_position(), grasp.object_position(), atol=1e-9)  # Not moved.
    assert np.linalg.norm(insert.object_position()[:2] - insert.goal[:2]) > 0.05
    assert insert.R_WP_hold is insert.R_WP_home  # No carry turn either.


def test_a_state_without_the_carried_fields_is_refused(envs):
    search, orient = envs["search"], envs["orient"]
    search.reset(seed=1)
    old = dataclasses.replace(search.get_state(), robot_positions=np.zeros(0))
    with pytest.raises(SceneHandoffError, match="collect the terminal buffer again"):
        orient.reset(options={"initial_state": old})


def test_counterparts_and_chain_checks(envs):
    assert counterpart("block_3_7", ["block_1", "block_3"]) == "block_3"
    assert counterpart("block_3", ["block_3", "block_3_1"]) == "block_3"
    with pytest.raises(SceneHandoffError, match="no counterpart"):
        counterpart("hammer", ["block_1"])
    with pytest.raises(SceneHandoffError, match="hammer"):
        check_handoff(["block_1", "hammer"], ["block_1"])
    chain = ChainEnv(["grasp", "insert"], envs=[envs["grasp"], envs["insert"]])  # Different scenes: accepted.
    observation, _ = chain.reset(seed=2)
    assert observation.shape == chain.observation_space.shape
