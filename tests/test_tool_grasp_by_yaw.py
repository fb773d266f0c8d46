"""``experiments/tool_grasp_by_yaw.py``: tool Grasp's records binned by the start yaw their seeds reset to, and bad
records refused with a message."""

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "experiments"))
import tool_grasp_by_yaw  # noqa: E402

RECORDS = ROOT / "results" / "tool_positioning"


def test_the_records_are_binned_by_the_yaw_their_seeds_reset_to(capsys):
    fist, pinch = RECORDS / "tool_grasp_script_seed3000.json", RECORDS / "tool_pinch_seed3000.json"
    tool_grasp_by_yaw.main([str(fist), str(pinch), "--bins", "4", "--test"])
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0] == "| Start yaw (rad) | Episodes | tool_grasp_script_seed3000 | tool_pinch_seed3000 |"
    rows = [line.strip("|").split("|") for line in lines[2:]]
    assert len(rows) == 5 and rows[-1][0].strip() == "all" and int(rows[-1][1]) == 4
    assert sum(int(row[1]) for row in rows[:-1]) == 4  # Every episode in one bin.
    # The yaws are the resets' own: seed 3000's hammer is laid at the yaw the env draws for it.
    from seqdex_drake.envs.subtask_env import make_env
    from seqdex_drake.tasks.registry import budget_config
    yaws = tool_grasp_by_yaw.start_yaws(make_env("tool_grasp", budget_config("tool_grasp")), [{"seed": 3000}] * 2)
    assert yaws[0] == yaws[1] and abs(yaws[0]) <= tool_grasp_by_yaw.YAW_RANGE + 0.05


@pytest.mark.parametrize("second, says", [
    ("tool_grasp_script_seed4000.json", "holds other episodes"),
    ("../building_blocks/grasp_in_pile.json", "not a rollout record|not tool_grasp"),
])
def test_records_of_other_episodes_are_refused(second, says):
    with pytest.raises(SystemExit, match=says):
        tool_grasp_by_yaw.main([str(RECORDS / "tool_grasp_script_seed3000.json"), str(RECORDS / second), "--test"])
