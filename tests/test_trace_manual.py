"""experiments/trace_manual.py: the main command's chain traced in the real diagram (the shipped checkpoints, seed 0):
a line per sample with the stage, whether the approach or the policy moves the arm and, during the retrieve, the
scripted retrieve's phase; bad input as one line."""

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parent.parent / "experiments" / "trace_manual.py"


def test_trace_shows_search_then_the_retrieves_phase():
    result = subprocess.run([sys.executable, str(SCRIPT), "--test"], capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    stages = [line.split()[3] for line in lines if line.startswith("block 1 t=")]  # block 1 t=T stage ...
    assert stages[0] == "search" and "retrieve" in stages, result.stdout
    retrieve = [line for line in lines if " retrieve " in line and "t=" in line]
    assert retrieve and all("@" in line.split()[5] for line in retrieve)  # phase@step
    assert retrieve[0].split()[5].split("@")[0] in ("grip", "lift", "regrip", "transfer")
    movers = [line.split()[4] for line in lines if line.startswith("block 1 t=")]
    assert movers[0] == "approach" and "policy" in movers, result.stdout  # The approach, then Search's policy.
    assert lines[-1].startswith("block 1 (block_5_") and "not placed" in lines[-1]


@pytest.mark.parametrize("flags, message", [
    (["--blocks", "9"], "--blocks must be in 1 .. 3"),
    (["--from-block", "0"], "--from-block must be in 1 .. 3"),
    (["--every", "0"], "--every must be > 0"),
    (["--seed", "-1"], "--seed"),
    (["--checkpoints", "/nonexistent"], "has no manifest.json"),
])
def test_bad_input_is_one_clear_line(flags, message):
    result = subprocess.run([sys.executable, str(SCRIPT), *flags], capture_output=True, text=True, timeout=300)
    assert result.returncode == 2 and message in result.stderr and "Traceback" not in result.stderr
