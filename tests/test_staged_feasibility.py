"""experiments/staged_feasibility.py: F^grasp fitted on Orient's hand-overs on the staging area. A short collection
writes its transitions (Orient's histories in the shipped Orient's layout, Grasp's outcome); a fit on hand-overs
with both outcomes writes an F the switcher can load for the Orient -> Grasp transition, with the shipped F's
figures beside its own; bad input is one clear line."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from seqdex_drake.chaining.feasibility_io import load_feasibility

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "experiments" / "staged_feasibility.py"


def script(*args, timeout=600):
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=timeout,
                          cwd=REPO)


def test_collect_then_fit_writes_an_f_for_the_orient_to_grasp_hand_over(tmp_path):
    collected = tmp_path / "t.npz"
    result = script("collect", "--test", "--out", str(collected))
    assert result.returncode == 0, result.stderr[-2000:]
    with np.load(collected) as data:
        histories, successes = data["histories"], data["successes"]
        assert histories.shape == (2, 15, 160) and successes.shape == (2,) and int(data["env_steps"]) > 0
    # Both outcomes are needed to fit: the 2 short episodes, repeated with one relabelled a success.
    mixed = tmp_path / "mixed.npz"
    np.savez(mixed, histories=np.repeat(histories, 10, axis=0), returns=np.arange(20.0),
             successes=np.arange(20) % 2 == 0, source_successes=np.zeros(20, dtype=bool))
    out = tmp_path / "grasp.pt"
    result = script("fit", str(mixed), "--folds", "0", "--out", str(out))
    assert result.returncode == 0, result.stderr[-2000:]
    outcome = json.loads(result.stdout[result.stdout.index("{"):result.stdout.rindex("}") + 1])
    assert outcome["label"] == "success" and outcome["threshold"] == 0.5 and outcome["hand_overs"] == 20
    assert 0.0 <= outcome["shipped_f_auc"] <= 1.0 and np.isfinite(outcome["shipped_f_mean_c"])
    f = load_feasibility(out)
    assert f.model.obs_dim == 160 and f.config.input_length == 10 and f.threshold == 0.5


@pytest.mark.parametrize("args, message", [
    (["fit", "/nonexistent.npz", "--out", "x.pt"], "no transitions file /nonexistent.npz"),
    (["collect", "--episodes", "0", "--out", "x.npz"], "--episodes must be >= 1"),
])
def test_bad_input_is_one_clear_line(args, message):
    result = script(*args, timeout=60)
    assert result.returncode == 2 and message in result.stderr and "Traceback" not in result.stderr


def test_a_fit_without_both_outcomes_is_refused_and_writes_nothing(tmp_path):
    only_failures = tmp_path / "f.npz"
    np.savez(only_failures, histories=np.zeros((4, 15, 160)), returns=np.zeros(4), successes=np.zeros(4, bool),
             source_successes=np.zeros(4, bool))
    out = tmp_path / "grasp.pt"
    result = script("fit", str(only_failures), "--out", str(out), timeout=120)
    assert result.returncode == 1 and "needs successes and failures" in result.stderr and not out.exists()
