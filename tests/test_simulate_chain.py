"""scripts/simulate_chain.py: both tasks run headless under --test, a recording is a real replay, and bad input
exits with one line naming the problem (no traceback)."""

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "scripts" / "simulate_chain.py"


def simulate(*args, timeout=240):
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=timeout,
                          cwd=REPO)


@pytest.mark.parametrize("task, untrained", [("building_blocks", False), ("tool_positioning", False),
                                              ("tool_positioning", True)])
def test_test_run_exits_zero_and_says_which_policies_run(task, untrained):
    result = simulate("--task", task, "--test", "--headless", *(["--untrained"] if untrained else []))
    assert result.returncode == 0, result.stderr[-2000:]
    # The repository's shipped checkpoints (checkpoints/<task>) run by default, and the script says so.
    shipped = (REPO / "checkpoints" / task / "manifest.json").is_file() and not untrained
    assert ("using the shipped checkpoints" in result.stdout) == shipped
    assert ("untrained policies:" in result.stdout) != shipped
    assert "state finite: True" in result.stdout
    first = "search" if task == "building_blocks" else "tool_grasp"
    assert "stage 1/" in result.stdout and first in result.stdout


def test_record_writes_a_standalone_replay(tmp_path):
    out = tmp_path / "replay.html"
    result = simulate("--task", "tool_positioning", "--test", "--record", str(out), "--port", "7230")
    assert result.returncode == 0, result.stderr[-2000:]
    assert "meshcat: open http://" in result.stdout
    html = out.read_text()
    assert len(html) > 500_000  # Meshes and the animation are inlined.
    assert html.lstrip().startswith("<!DOCTYPE html>") and "meshcat" in html  # Rendered in tests/test_browser.py.


@pytest.mark.parametrize("args, message", [
    (["--manual", "nope"], "assembly manual 'nope' not found"),
    (["--checkpoints", "/nonexistent/run"], "--checkpoints /nonexistent/run does not exist"),
])
def test_bad_input_is_one_clear_line(args, message):
    result = simulate(*args, "--test", "--headless")
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr


def test_bad_manual_content_and_mismatched_feasibility_file(tmp_path):
    manual = tmp_path / "bad.yaml"
    manual.write_text("steps:\n- {block_type: 12, cell: [0, 0]}\n")
    result = simulate("--manual", str(manual), "--test", "--headless")
    assert result.returncode == 2 and "unknown block type 12" in result.stderr
    assert "Traceback" not in result.stderr
    from seqdex_drake.chaining.feasibility import FeasibilityConfig, build_feasibility_model
    from seqdex_drake.chaining.feasibility_io import save_feasibility
    from seqdex_drake.tasks.run_config import observation_spec

    config = FeasibilityConfig(history=2, d_model=8, heads=2, layers=1, feedforward=8)
    (tmp_path / "run" / "feasibility").mkdir(parents=True)
    # An F made for Orient's observations, where tool Reorient's F must read tool Grasp's.
    save_feasibility(tmp_path / "run" / "feasibility" / "tool_reorient.pt", build_feasibility_model(159, config),
                     config, 1.0, observation_spec("orient", 159), source_task="orient", target_task="tool_reorient")
    result = simulate("--task", "tool_positioning", "--checkpoints", str(tmp_path / "run"), "--test", "--headless")
    assert result.returncode == 2, result.stdout[-1000:]
    assert "tool_reorient.pt" in result.stderr and "Traceback" not in result.stderr
