"""Paired comparisons of evaluation rows (seqdex_drake/evaluation/paired.py, scripts/paired_table.py): the exact
McNemar p-value against scipy's binomial test and the recorded tool-chain figures, pairing on shared episodes
only, and bad input as one clear line."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import binomtest

from seqdex_drake.evaluation.paired import compare, load_outcomes, mcnemar_p, paired_table

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "paired_table.py"


def _row(folder: Path, outcomes: dict, extra: tuple = ()) -> Path:
    folder.mkdir(parents=True)
    lines = [json.dumps({"experiment": "main", "setting": 3, "seed": s, "object": o, "episode": e, "success": v})
             for (s, o, e), v in outcomes.items()]
    lines += [json.dumps(record) for record in extra]
    (folder / "episodes.jsonl").write_text("\n".join(lines) + "\n")
    return folder


def test_mcnemar_p_is_the_exact_binomial_test_of_the_discordant_pairs():
    rng = np.random.default_rng(0)
    for _ in range(30):
        b, c = (int(x) for x in rng.integers(0, 25, size=2))
        expected = 1.0 if b + c == 0 else binomtest(b, b + c, 0.5).pvalue
        assert mcnemar_p(b, c) == pytest.approx(expected, rel=1e-12)
    assert mcnemar_p(13, 1) == pytest.approx(30 / 2**14)  # The tool chain's R + F vs R figure (p ~ 0.002).
    assert mcnemar_p(2, 5) == pytest.approx(58 / 128)  # Switcher vs sequential (p ~ 0.45).
    with pytest.raises(ValueError, match=">= 0"):
        mcnemar_p(-1, 2)


def test_rows_pair_on_the_episodes_both_played(tmp_path):
    first = _row(tmp_path / "a", {(0, 0, 0): True, (0, 0, 1): True, (0, 0, 2): False, (1, 0, 0): True},
                 extra=({"experiment": "history", "seed": 0, "object": 0, "episode": 0, "success": False},))
    second = _row(tmp_path / "b", {(0, 0, 0): True, (0, 0, 1): False, (0, 0, 2): True, (2, 0, 0): False})
    outcomes = load_outcomes(first)
    assert outcomes[(0, 0, 0)] is True and len(outcomes) == 4  # The ablation's record is not the main row's.
    c = compare("a", outcomes, "b", load_outcomes(second / "episodes.jsonl"))
    assert (c.episodes, c.first_successes, c.second_successes, c.both, c.only_first, c.only_second) == (3, 2, 2, 1,
                                                                                                         1, 1)
    assert c.p == 1.0
    table = paired_table([("a", "b")], {"a": first, "b": second})
    assert "| a vs b | 3 | 2 / 2 | 1 | 1 | 1 | 1 |" in table
    with pytest.raises(ValueError, match="share no episode"):
        compare("a", {(0, 0, 0): True}, "b", {(5, 0, 0): True})
    with pytest.raises(ValueError, match="no row named 'c'"):
        paired_table([("a", "c")], {"a": first, "b": second})


def test_the_script_writes_the_table_and_refuses_bad_input(tmp_path):
    first = _row(tmp_path / "a", {(0, 0, k): k < 8 for k in range(10)})
    second = _row(tmp_path / "b", {(0, 0, k): k < 1 for k in range(10)})
    out = tmp_path / "table.md"
    done = subprocess.run([sys.executable, str(SCRIPT), "--row", f"ours={first}", "--row", f"base={second}",
                           "--pair", "ours:base", "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "| ours vs base | 10 | 8 / 1 | 1 | 7 | 0 | 0.0156 |" in out.read_text() == done.stdout
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "episodes.jsonl").write_text("{not json\n")
    for args, message in [(["--row", "ours", "--pair", "ours:base"], "write NAME=DIR"),
                          (["--row", f"ours={first}", "--pair", "ours"], "two row names"),
                          (["--row", f"ours={tmp_path / 'none'}", "--pair", "ours:ours"], "no such file"),
                          (["--row", f"ours={tmp_path / 'broken'}", "--pair", "ours:ours"], "broken/episodes.jsonl:1")]:
        bad = subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=120)
        assert bad.returncode == 2 and message in bad.stderr and "Traceback" not in bad.stderr, bad.stderr


def test_main_command_records_pair_by_seed_and_manual_step(tmp_path):
    """The main command's records (experiments/main_command_seeds.py) are rows too: the recorded first-block figures
    with and without the switcher (results/building_blocks.md: 17 and 15 of 32, 5 and 3 discordant)."""
    records = Path(__file__).resolve().parent.parent / "results" / "building_blocks"
    switcher = load_outcomes(records / "main_command_first_block.json")
    assert len(switcher) == 32 and set(switcher) == {(seed, 0, 0) for seed in range(32)}
    c = compare("switcher", switcher, "sequential", load_outcomes(records / "main_command_first_block_sequential.json"))
    assert (c.episodes, c.first_successes, c.second_successes, c.only_first, c.only_second) == (32, 17, 15, 5, 3)
    assert c.p == pytest.approx(mcnemar_p(5, 3))
    manual = load_outcomes(records / "main_command_manual.json")
    assert len(manual) == 48 and sum(manual[(seed, 1, 0)] for seed in range(32) if (seed, 1, 0) in manual) == 7
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"per_block": [{"seed": 0}]}))
    with pytest.raises(ValueError, match="not a main_command_seeds.py or seqdex rollout record"):
        load_outcomes(bad)
    result = subprocess.run([sys.executable, str(SCRIPT), "--row", f"a={bad}", "--row", f"b={bad}", "--pair", "a:b"],
                            capture_output=True, text=True)
    assert result.returncode == 2 and "not a main_command_seeds.py or seqdex rollout record" in result.stderr


def test_rollout_records_pair_by_seed_and_several_files_make_one_row(tmp_path):
    """``seqdex rollout --out`` records are rows (a sub-task alone, paired by episode seed); files joined by commas
    make one row, as a row of three 100-episode seeds."""
    def record(path, seed, successes):
        episodes = [{"seed": seed + i, "success": bool(s), "return": 0.0, "length": 150}
                    for i, s in enumerate(successes)]
        path.write_text(json.dumps({"task": "tool_grasp", "seed": seed, "per_episode": episodes}))
        return str(path)

    first = ",".join([record(tmp_path / "a0.json", 0, [1, 1, 0]), record(tmp_path / "a1.json", 100, [1, 1])])
    second = ",".join([record(tmp_path / "b0.json", 0, [0, 1, 0]), record(tmp_path / "b1.json", 100, [0, 0])])
    outcomes = load_outcomes(first)
    assert outcomes == {(0, 0, 0): True, (1, 0, 0): True, (2, 0, 0): False, (100, 0, 0): True, (101, 0, 0): True}
    c = compare("pinch", outcomes, "fist", load_outcomes(second))
    assert (c.episodes, c.first_successes, c.second_successes, c.only_first, c.only_second) == (5, 4, 1, 3, 0)
