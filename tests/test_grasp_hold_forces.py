"""experiments/grasp_hold_forces.py: Grasp's jaw pinch on the staging area, the contact force per digit on the lifted
block and its tilt through the lift, in Grasp's real env; bad input as one clear line."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "experiments" / "grasp_hold_forces.py"
sys.path.insert(0, str(ROOT / "experiments"))


def test_the_script_lifts_a_1x4_and_its_three_jaw_tips_press_on_it(tmp_path):
    import grasp_hold_forces

    out = tmp_path / "hold.json"
    assert grasp_hold_forces.main(["--seeds", "0", "--types", "5", "--out", str(out)]) == 0
    record = json.loads(out.read_text())
    episode, summary = record["episodes"][0], record["summary"]
    assert episode["success"] and episode["block"].startswith("block_5")
    forces = episode["forces"]
    assert all(forces.get(digit, 0.0) > 0.0 for digit in ("index", "middle", "thumb")), forces
    assert "table" not in forces and -1.0 <= episode["least_up"] <= 1.0  # Lifted: off the table.
    assert summary["episodes"] == summary["lifted"] == 1 and summary["upright"] == int(episode["upright"])
    assert summary["median_force_lifted"]["thumb"] == forces["thumb"]


@pytest.mark.parametrize("flags, message", [
    (["--seeds", "x"], "--seeds"),
    (["--types", "9"], "--types takes block types 1-8"),
    (["--checkpoint", "/nonexistent.pt"], "is not a file"),
])
def test_bad_input_is_one_clear_line(flags, message):
    result = subprocess.run([sys.executable, str(SCRIPT), *flags], capture_output=True, text=True, timeout=300)
    assert result.returncode == 2 and message in result.stderr and "Traceback" not in result.stderr
