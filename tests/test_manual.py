"""Assembly manuals: the shipped ones load; bad manuals fail with a message naming the step and the problem."""

import numpy as np
import pytest

from seqdex_drake import LoadScenario
from seqdex_drake.harness import MakeStationHarness
from seqdex_drake.manual import (
    BOARD_ORIGIN,
    BOARD_TOP,
    LoadManual,
    ManualError,
    ManualNames,
    ManualStep,
    goal_pose,
    pinch_conflicts,
)


def test_shipped_manuals_load():
    assert {"small_wall", "mixed_shapes"} <= set(ManualNames())
    for name in ManualNames():
        manual = LoadManual(name)
        assert manual.steps and manual.name
        for step in manual.steps:
            X = goal_pose(step)
            assert np.all(np.abs(X.translation()[:2] - BOARD_ORIGIN[:2]) < 0.18)
            assert X.translation()[2] >= BOARD_TOP - 1e-9


def test_pinch_conflicts_name_a_block_beside_an_earlier_one_along_x_and_the_shipped_manuals_have_none():
    """Grasp's pinch holds a block by its +-x faces; a block 3 cm wide beside another along x leaves no room."""
    text = """steps:
- {block_type: 5, cell: [5, 8], level: 0, yaw_deg: 90}
- {block_type: 4, cell: [6, 8], level: 0, yaw_deg: 90}
- {block_type: 1, cell: [5, 1], level: 0, yaw_deg: 90}
- {block_type: 4, cell: [5, 4], level: 0, yaw_deg: 90}
- {block_type: 1, cell: [7, 2], level: 0, yaw_deg: 90}
- {block_type: 1, cell: [5, 9], level: 1, yaw_deg: 90}
"""
    problems = pinch_conflicts(LoadManual(text=text))
    # Step 2 beside step 1 along x; step 4 touches step 3 end to end along y (fine); step 5 has a free cell between
    # it and step 3 (fine); step 6 on top of step 1 has nothing beside it at its level (step 2 is one level below).
    assert len(problems) == 1 and problems[0].startswith("step 2 (block 4): step(s) [1]")
    for name in ManualNames():
        assert pinch_conflicts(LoadManual(name)) == [], name


def test_cell_goals_are_on_the_stud_grid():
    # A 1x4 block at cell [4, 9], yaw 0: footprint cells 4-7 along x -> centred on the board in x.
    X = goal_pose(ManualStep(block_type=5, cell=[4, 9], level=0))
    np.testing.assert_allclose(X.translation(), [0.25, -0.35 + 3.5 * 0.03, BOARD_TOP], atol=1e-12)
    X = goal_pose(ManualStep(block_type=5, cell=[0, 0], level=2, yaw_deg=90))  # 1x4 turned: 1 cell in x, 4 in y
    np.testing.assert_allclose(X.translation(), [0.25 - 5.5 * 0.03, -0.35 - 4 * 0.03, BOARD_TOP + 2 * 0.0375],
                               atol=1e-12)


def test_board_constants_match_the_chain_scene():
    harness = MakeStationHarness(LoadScenario("building_blocks/chain"))
    plant = harness.station.GetSubsystemByName("plant")
    X = plant.EvalBodyPoseInWorld(plant.GetMyContextFromRoot(harness.context), plant.GetBodyByName("baseplate"))
    np.testing.assert_allclose(X.translation(), BOARD_ORIGIN, atol=1e-12)
    assert len(harness.objects.names) == 72


@pytest.mark.parametrize("text, message", [
    ("{steps: [{block_type: 9, cell: [0, 0]}]}", r"step 1: unknown block type 9; valid types are \[1, 2"),
    ("{steps: [{block_type: 5, cell: [9, 0]}]}", r"step 1 \(block 5\): goal off the board.*at most \[8, 11\]"),
    ("{steps: [{block_type: 1, cell: [-1, 0]}]}", "goal off the board"),
    ("{steps: [{block_type: 1, position: [0.6, -0.35, 0.618]}]}", "goal off the board"),
    ("{steps: [{block_type: 1, position: [0.25, -0.35, 0.5]}]}", r"z = 0.5 m is not between"),
    ("{steps: [{block_type: 1, cell: [0, 0]}, {block_type: 2, cel: [1, 1]}]}", r"step 2: unknown key\(s\) \['cel'\]"),
    ("{titel: x, steps: [{block_type: 1, cell: [0, 0]}]}", r"unknown key\(s\) \['titel'\]"),
    ("{steps: [{block_type: 1}]}", "either as 'cell'"),
    ("{steps: [{block_type: 1, cell: [0, 0], position: [0.25, -0.35, 0.62]}]}", "exactly one"),
    ("{steps: [{block_type: 1, cell: [0, 0], yaw_deg: 45}]}", "multiple of 90"),
    ("{steps: [{block_type: 1, cell: [0, 0]}, {block_type: 7, cell: [1, 0]}]}", r"step 2 .*already taken by step 1"),
    ("{steps: [{block_type: 1, cell: [0, 0], level: 1}]}", "nothing under it"),
    ("{steps: [{block_type: one, cell: [0, 0]}]}", r"step 1: unknown block type .one."),
    ("{steps: []}", "no steps"),
    ("{steps: [unclosed", "malformed YAML"),
])
def test_bad_manuals_name_the_problem(text, message):
    with pytest.raises(ManualError, match=message):
        LoadManual(text=text)


def test_missing_manual_lists_the_shipped_ones(tmp_path):
    with pytest.raises(ManualError, match="not found.*small_wall"):
        LoadManual(tmp_path / "nope.yaml")
    path = tmp_path / "ok.yaml"
    path.write_text("name: ok\nsteps:\n- {block_type: 8, cell: [0, 0], level: 0}\n"
                    "- {block_type: 7, cell: [1, 1], level: 1}\n")
    assert [s.block_type for s in LoadManual(path).steps] == [8, 7]
