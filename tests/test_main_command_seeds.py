"""experiments/main_command_seeds.py: the main command's chain over seeds; a short run writes its block's record, bad
input is one clear line."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "experiments" / "main_command_seeds.py"


def seeds_script(*args, timeout=300):
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=timeout,
                          cwd=REPO)


def test_short_run_writes_the_first_blocks_record(tmp_path):
    out = tmp_path / "seeds.json"
    result = seeds_script("--test", "--out", str(out))
    assert result.returncode == 0, result.stderr[-2000:]
    record = json.loads(out.read_text())
    assert record["seeds"] == [0] and record["blocks"] == 1 and record["placed_per_step"] == [0]
    assert record["refetches"] == 0 and record["trigger"] == "next" and record["piles"] == "eval"
    # The finished record (written after every seed; "seeds_done" only while seeds remain), its whole-manual list.
    assert "seeds_done" not in record and record["manual_placed"] == [] and record["machine"].startswith("CPU ")
    (row,) = record["per_block"]
    assert row["seed"] == 0 and row["step"] == 0 and row["block_type"] == 5 and row["block"].startswith("block_5_")
    # Cut to 0.5 s: Search has barely started, the block is still in the box, far from its goal on the baseplate.
    assert not row["placed"] and row["time"] == pytest.approx(0.5, abs=0.02) and row["position_error"] > 0.2
    assert row["refetches"] == 0 and row["fetched"] == row["block"]
    assert "placed per manual step [0] of 1 seeds" in result.stdout


@pytest.mark.parametrize("args, message", [
    (["--seeds", "5-2"], "the range '5-2' is empty"),
    (["--seeds", "x"], "'x' is not a seed or a range like 0-31"),
    (["--seeds", "0-5000"], "at most 1000 seeds"),
    (["--blocks", "4"], "--blocks must be in 1 .. 3"),
    (["--workers", "0"], "--workers must be >= 1"),
    (["--refetches", "-1"], "--refetches must be >= 0"),
    (["--trigger", "often"], "--trigger must be one of next, any_later, decision"),
    (["--piles", "all"], "--piles must be one of eval, tune, train"),
    (["--checkpoints", "/nonexistent/run"], "has no manifest.json"),
    (["--manual", "/nonexistent/manual.yaml"], "not found"),
    (["--manual", "/bin/ls"], "cannot read it as a YAML assembly manual"),
])
def test_bad_input_is_one_clear_line(args, message):
    result = seeds_script(*args, timeout=60)
    assert result.returncode == 2 and message in result.stderr
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr


def test_the_tuning_piles_are_32_settled_piles_none_of_them_a_held_out_one():
    """``--piles tune``: 32 piles of the 72 blocks, all inside the box, none the same as a held-out (``eval``) pile
    or a training one, so tuning the chain on them leaves the held-out piles unseen."""
    import numpy as np

    sys.path.insert(0, str(REPO / "experiments"))
    from main_command_seeds import PILE_FILES

    from seqdex_drake.scene.piles import InsideBox

    piles = {name: np.load(REPO / "models" / "piles" / file)["q"] for name, file in PILE_FILES.items()}
    assert piles["tune"].shape == (32, 72, 7) and piles["eval"].shape[1:] == (72, 7)
    assert all(np.all(InsideBox(pile)) for pile in piles["tune"])
    for other in ("eval", "train"):
        gaps = np.abs(piles["tune"][:, None] - piles[other][None]).max(axis=(2, 3))
        assert gaps.min() > 0.01, other  # Some block more than 1 cm elsewhere in every pair of piles.
