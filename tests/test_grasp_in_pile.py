"""experiments/grasp_in_pile.py: Grasp measured inside the pile with the target stood upright in place; a short run
writes its episode (the block stood upright in the whole pile when Grasp started), bad input is one clear line."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "experiments" / "grasp_in_pile.py"


def grasp_in_pile(*args, timeout=300):
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=timeout,
                          cwd=REPO)


def test_short_run_stands_the_block_up_in_the_pile_and_writes_its_episode(tmp_path):
    out = tmp_path / "grasp_in_pile.json"
    # Seed 2: a block that stays upright when stood up in place (at seed 1 the pick topples: which picks do
    # depends on the last bits of the arithmetic, seqdex_drake/numerics.py; seeds 2-5 all stand).
    result = grasp_in_pile("--test", "--seed", "2", "--out", str(out))
    assert result.returncode == 0, result.stderr[-2000:]
    record = json.loads(out.read_text())
    assert record["episodes"] == 1 and len(record["per_episode"]) == 1
    episode = record["per_episode"][0]
    assert episode["block_type"] == 1 and episode["block"].startswith("block_1_")
    assert episode["stood"], "the block stood up in place did not stay upright until Grasp started"
    # Grasp is cut to 20 steps under --test: its scripted lift (from step 48) has not begun.
    assert abs(episode["rise"]) < 0.05 and not episode["lifted"]
    assert record["stood"] == 1 and record["lifted"] == 0
    assert "upright blocks lifted" in result.stdout


@pytest.mark.parametrize("args, message", [
    (["--episodes", "0"], "--episodes must be >= 1"),
    (["--checkpoints", "/nonexistent/run"], "--checkpoints /nonexistent/run is not a directory"),
])
def test_bad_input_is_one_clear_line(args, message):
    result = grasp_in_pile(*args)
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr
