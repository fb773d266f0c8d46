"""Settled piles: nothing escapes the box, resting penetration < 2 mm, deterministic, versioned cache."""

import numpy as np
import pytest

from seqdex_drake import LoadScenario
from seqdex_drake.harness import MakeStationHarness, ResolvePackageUrl
from seqdex_drake.scene.piles import SETTLE_TIME_STEP, InsideBox, LoadPiles, PileSettings, SavePiles, SettlePile

SETTLING = f"plant_config: {{time_step: {SETTLE_TIME_STEP}}}"  # The step the cached piles were settled at.
SMALL_PILE = """{
  """ + SETTLING + """,
  object_layout: parked,
  freeze: {enabled: false},
  cameras: {},
  directives: [
    {add_directives: {file: package://seqdex_models/franka_allegro.dmd.yaml}},
    {add_directives: {file: package://seqdex_models/fixtures_box.dmd.yaml}},
""" + "".join(
    f"    {{add_model: {{name: block_{t}_{k}, file: package://seqdex_models/blocks/block_{t}/block_{t}_coarse.sdf}}}},\n"
    for t in (1, 4, 5, 7) for k in range(3)) + "  ]}"


def max_penetration(harness) -> float:
    pairs = harness.port("query_object").ComputePointPairPenetration()
    return max((p.depth for p in pairs), default=0.0)


def test_cached_pile_rests_inside_the_box():
    scenario = LoadScenario("building_blocks/search", scenario_text=f"{{freeze: {{enabled: false}}, {SETTLING}}}")
    harness = MakeStationHarness(scenario, pile_index=0)
    start = harness.objects.positions(harness.context)
    assert InsideBox(start).all()
    harness.step(30)  # Every block dynamic for 0.5 s.
    end = harness.objects.positions(harness.context)
    assert InsideBox(end).all(), "a block left the box"
    assert max_penetration(harness) < 0.002
    # Quasi-static: with point contact an all-dynamic pile keeps creeping slowly
    # (docs/architecture.md, "Physics choices").
    assert np.median(np.linalg.norm(end[:, 4:] - start[:, 4:], axis=1)) < 0.0015, "the cached pile was not settled"


def test_settling_is_deterministic_and_stays_in_the_box():
    scenario = LoadScenario("building_blocks/search", scenario_text=SMALL_PILE)
    settings = PileSettings(batch_seconds=0.5, relax_seconds=0.3)
    piles = []
    for _ in range(2):
        harness = MakeStationHarness(scenario)
        piles.append(SettlePile(harness.simulator, harness.objects, seed=3, settings=settings))
        assert InsideBox(piles[-1]).all()
        assert max_penetration(harness) < 0.002
    np.testing.assert_array_equal(piles[0], piles[1])


def test_pile_cache_round_trip_and_checks(tmp_path):
    names = ["block_1_0", "block_2_0"]
    q = np.tile([1.0, 0, 0, 0, 0.25, 0.19, 0.6], (3, 2, 1))
    path = tmp_path / "piles.npz"
    SavePiles(path, q, names, "test")
    np.testing.assert_array_equal(LoadPiles(path, names), q)
    with pytest.raises(ValueError, match="other objects"):
        LoadPiles(path, ["block_1_0"])
    with pytest.raises(FileNotFoundError, match="generate_piles.py"):
        LoadPiles(tmp_path / "missing.npz", names)
    np.savez(tmp_path / "old.npz", version=0, q=q, object_names=np.array(names), scenario=np.array("x"))
    with pytest.raises(ValueError, match="format version"):
        LoadPiles(tmp_path / "old.npz", names)


def test_shipped_cache_matches_the_search_scenario():
    scenario = LoadScenario("building_blocks/search")
    harness = MakeStationHarness(scenario, pile_index=1)
    piles = LoadPiles(ResolvePackageUrl(scenario.pile_file), harness.objects.names)
    assert piles.shape[1:] == (72, 7) and len(piles) >= 4
    assert all(InsideBox(p).all() for p in piles)


def test_search_pile_stays_put_for_ten_seconds_at_the_search_step():
    """The Search scene as an episode starts it (blocks away from the target frozen), at its 1/240 s plant step
    with the robot away: after 10 s nothing crept or left the box, and every block is frozen again."""
    scenario = LoadScenario("building_blocks/search")
    assert scenario.plant_config.time_step > 0.004  # The step this test is about (the scenario's).
    harness = MakeStationHarness(scenario, pile_index=0)
    q = harness.objects.positions(harness.context)
    target = int(np.argmin(np.linalg.norm(q[:, 4:6] - [0.25, 0.19], axis=1)))
    harness.objects.freeze_far_from(harness.context, q[target, 4:])
    assert 0 < (~harness.objects.frozen_mask(harness.context)).sum() < 10
    start = harness.objects.positions(harness.context)
    harness.step(600)
    end = harness.objects.positions(harness.context)
    moved = np.linalg.norm(end[:, 4:] - start[:, 4:], axis=1)
    assert InsideBox(end).all(), "a block left the box"
    assert moved.max() < 0.01 and np.percentile(moved, 95) < 5e-4, f"the pile crept: {np.sort(moved)[-5:]} m"
    assert harness.objects.frozen_mask(harness.context).all(), "resting blocks did not freeze again"
    assert max_penetration(harness) < 0.002


def test_a_digging_hand_does_not_blow_up_the_pile():
    """Random finger actions in the Search env (an untrained policy digs like this): blocks stay in the box, move
    at hand speeds and do not sink into each other or the hand by more than a couple of centimetres."""
    from seqdex_drake.envs.subtask_env import make_env

    env = make_env("search")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    station_context = env.station.GetMyContextFromRoot(env.context)
    deepest, fastest = 0.0, 0.0
    for _ in range(40):
        env.step(rng.uniform(-1, 1, env.action_space.shape))
        pairs = env.station.GetOutputPort("query_object").Eval(station_context).ComputePointPairPenetration()
        deepest = max([deepest] + [p.depth for p in pairs])
        fastest = max([fastest] + [np.linalg.norm(env.plant.EvalBodySpatialVelocityInWorld(
            env.plant_context, body).translational()) for body in env.objects.bodies])
    assert InsideBox(env.objects.positions(env.context)).all()
    assert deepest < 0.025, f"penetration {deepest:.4f} m"
    assert fastest < 2.0, f"a block flew at {fastest:.2f} m/s"


def _block(p, roll=0.0):
    """A pile row [wxyz, xyz]: rolled by ``roll`` about x, at ``p``."""
    return np.array([np.cos(roll / 2), np.sin(roll / 2), 0.0, 0.0, *p])


def test_accessibility_order_prefers_reachable_upright_uncovered_then_side_then_high():
    from seqdex_drake.tasks.blocks_common import accessibility_order, reachable_region

    low, high = reachable_region()
    mid = (low + high) / 2
    q = np.array([
        _block([*mid, 0.62]),                                   # 0: upright, reachable, uncovered
        _block([*(mid + [0.06, 0.0]), 0.63], np.pi / 2),        # 1: on its side, reachable
        _block([*(mid + [0.0, 0.06]), 0.66], np.pi),            # 2: upside down, reachable, highest
        _block([low[0] - 0.05, mid[1], 0.70]),                  # 3: upright, highest, but where the hand cannot fit
        _block([*(mid + [-0.06, 0.0]), 0.61]),                  # 4: upright, reachable, covered by 5
        _block([*(mid + [-0.05, 0.01]), 0.67], np.pi / 2),      # 5: on its side over 4
    ])
    assert accessibility_order(q, [0, 1, 2, 3, 4]) == [0, 4, 1, 2, 3]  # Upright, even covered, before the others.
    assert accessibility_order(q, [1, 5]) == [5, 1]  # The same pose: the higher first.
    assert accessibility_order(q, [2, 1]) == [1, 2]
    q[1, 6] = 0.70  # Same pose class: the higher one first.
    q[0] = _block([*(mid + [0.12, 0.0]), 0.64], np.pi / 2)
    assert accessibility_order(q, [0, 1]) == [1, 0]


def test_accessibility_order_prefers_blocks_resting_on_others_to_blocks_on_the_box_floor():
    from seqdex_drake.scene.piles import BOX_CENTER
    from seqdex_drake.tasks.blocks_common import ON_FLOOR, accessibility_order, pick_keys, reachable_region

    low, high = reachable_region()
    mid = (low + high) / 2
    floor = BOX_CENTER[2]
    q = np.array([
        _block([*mid, floor + 0.0005]),                          # 0: upright on the floor (centre 2.9 cm up)
        _block([*(mid + [0.08, 0.0]), floor + 0.05], np.pi / 2),  # 1: on its side, on other blocks
        _block([*(mid + [0.0, 0.08]), floor + 0.016], np.pi / 2),  # 2: on its side on the floor
    ])
    assert [pick_keys(q, i)["on_floor"] for i in range(3)] == [True, False, True]
    assert accessibility_order(q, [0, 1, 2]) == [1, 0, 2]  # On others first; on the floor, upright first.
    q[0, 6] = floor + ON_FLOOR  # The upright block raised onto others: its centre 6.4 cm above the floor.
    assert accessibility_order(q, [0, 1, 2]) == [0, 1, 2]


def test_accessibility_order_prefers_at_most_a_quarter_roll_from_upright():
    from seqdex_drake.tasks.blocks_common import QUARTER_ROLL, accessibility_order, reachable_region

    low, high = reachable_region()
    mid = (low + high) / 2
    q = np.array([
        _block([*(mid - [0.08, 0.0]), 0.70], np.radians(QUARTER_ROLL + 20.0)),  # 0: highest, past a quarter roll
        _block([*(mid + [0.08, 0.0]), 0.66], np.radians(60.0)),                 # 1: leaning, 60 deg from upright
        _block([*(mid - [0.0, 0.08]), 0.69], np.radians(QUARTER_ROLL - 1.0)),  # 2: on a side, tilted a bit back
    ])
    assert accessibility_order(q, [0, 1, 2]) == [2, 1, 0]  # Within a quarter roll first; then the higher.


def _yawed(p, yaw, roll=0.0):
    """A pile row turned by ``yaw`` about world z after ``roll`` about x, at ``p``."""
    from pydrake.math import RollPitchYaw

    return np.r_[RollPitchYaw(roll, 0.0, yaw).ToQuaternion().wxyz(), p]


def test_roll_blocked_needs_a_neighbour_as_high_on_every_side_the_roll_can_take():
    from seqdex_drake.tasks.blocks_common import roll_blocked

    mid = np.array([0.25, 0.19, 0.62])
    side = _block(mid, np.pi / 2)  # Body +y up: its top face moves toward +y as it stands up.
    ahead, behind, low = _block(mid + [0.02, 0.06, 0.0]), _block(mid - [0.0, 0.06, 0.0]), _block(mid + [0, 0.06, -0.03])
    far = _block(mid + [0.10, 0.06, 0.0])  # Beyond the block's end.
    assert roll_blocked(np.array([side, ahead]), 0)
    assert not roll_blocked(np.array([side, behind]), 0)
    assert not roll_blocked(np.array([side, low]), 0)
    assert not roll_blocked(np.array([side, far]), 0)
    assert roll_blocked(np.array([_block(mid, -np.pi / 2), behind]), 0)  # The other side up: the roll goes to -y.
    upside_down = _block(mid, np.pi)  # Either way: blocked only when both are.
    assert not roll_blocked(np.array([upside_down, ahead]), 0)
    assert roll_blocked(np.array([upside_down, ahead, behind]), 0)
    assert not roll_blocked(np.array([_block(mid), ahead, behind]), 0)  # Upright: nothing to roll.


def test_accessibility_order_prefers_room_to_roll_then_a_long_axis_across_the_jaws():
    from seqdex_drake.tasks.blocks_common import accessibility_order, along_jaws, reachable_region

    assert along_jaws(_yawed([0.25, 0.19, 0.62], 0.3)) and not along_jaws(_yawed([0.25, 0.19, 0.62], np.pi / 2 - 0.3))
    low, high = reachable_region()
    mid = np.r_[(low + high) / 2, 0.62]
    q = np.array([
        _yawed(mid, 0.0, np.pi / 2),                            # 0: on its side along the jaws, roll to +y free
        _yawed(mid + [0.0, -0.09, 0.0], np.pi / 2, np.pi / 2),  # 1: on its side across the jaws, roll to -x free
        _yawed(mid + [0.10, 0.05, 0.01], 0.0, np.pi / 2),       # 2: highest, on its side, its roll (+y) taken by 3
        _block(mid + [0.10, 0.11, 0.01]),                       # 3
    ])
    assert accessibility_order(q, [0, 1, 2]) == [1, 0, 2]


def test_the_chain_is_evaluated_on_held_out_piles():
    """The whole-chain scene restores piles that Search did not train on: another cache, every pile in the box."""
    search, chain = LoadScenario("building_blocks/search"), LoadScenario("building_blocks/chain")
    names = MakeStationHarness(chain).objects.names
    trained = LoadPiles(ResolvePackageUrl(search.pile_file), names)
    held_out = LoadPiles(ResolvePackageUrl(chain.pile_file), names)
    assert chain.pile_file != search.pile_file and len(held_out) >= 24
    assert all(InsideBox(p).all() for p in held_out)
    assert min(np.abs(p - q).max() for p in held_out for q in trained) > 0.01  # No training pile among them.
