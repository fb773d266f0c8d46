"""seqdex evaluate: --test writes the success table (paper layout), both ablations, the pose scatter (with
points when a feasibility function exists) and resumes from its episode records; bad input is an InputError."""

import argparse
import csv
import json

import numpy as np
import pytest

from seqdex_drake.chaining.feasibility import FeasibilityConfig, build_feasibility_model
from seqdex_drake.chaining.feasibility_io import save_feasibility
from seqdex_drake.cli import evaluate
from seqdex_drake.tasks.run_config import observation_spec
from seqdex_drake.user_input import InputError


def parse(*argv):
    parser = argparse.ArgumentParser()
    evaluate.add_parser(parser.add_subparsers(dest="command"))
    return parser.parse_args(["evaluate", *argv])


def test_evaluate_test_writes_tables_and_plot(tmp_path):
    run_dir = tmp_path / "run"
    (run_dir / "feasibility").mkdir(parents=True)
    config = FeasibilityConfig(history=3, d_model=16, heads=2, layers=1, feedforward=16)
    # An untrained F for tool grasp -> tool reorient; a tiny threshold makes its positive scores exceed 1.
    save_feasibility(run_dir / "feasibility" / "tool_reorient.pt", build_feasibility_model(159, config), config, 1e-6,
                     observation_spec("tool_grasp", 159), source_task="tool_grasp", target_task="tool_reorient")
    assert evaluate.run(parse("--task", "tool_positioning", "--run-dir", str(run_dir), "--test")) == 0
    out = run_dir / "evaluation"
    table = (out / "table2_tool_positioning.md").read_text()
    assert "| hammer | spatula | spoon | trained | unseen | all |" in table
    assert "0.00 ± 0.00" in table and "untrained stages: tool_grasp, tool_reorient" in table
    rows = list(csv.DictReader((out / "table2_tool_positioning.csv").open()))
    assert rows[0]["all_n"] == "1" and float(rows[0]["all_mean"]) == 0.0
    switching = (out / "ablation_switching.md").read_text()
    assert all(f"max {k} switches" in switching for k in range(4))
    assert "H = 5 skipped: missing" in (out / "ablation_history.md").read_text()
    png = (out / "feasibility_pose_scatter.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    points = list(csv.DictReader((out / "feasibility_pose_scatter.csv").open()))
    records = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    ticks = sum(round(r["time"] * 60) for r in records if r["experiment"] == "main")
    assert len(points) == ticks > 0, (len(points), ticks)  # every control tick of the 3 main episodes is scored
    assert len(records) == 3 + 4  # 3 tools, then the hammer for each switch cap
    assert {r["experiment"] for r in records} == {"main", "switching"}
    assert {r["start"]["tool"] for r in records if r["experiment"] == "main"} == {"hammer", "spatula", "spoon"}
    # Each record says how the object was as each stage started: [its z axis's world z, its lift (m)].
    entry = records[0]["stage_entries"]["tool_grasp"]
    assert -1.0 <= entry[0] <= 1.0 and abs(entry[1]) < 0.01  # Grasp starts with the tool on the table.
    assert "object lifted >= 0.1 m when Reorient started: 0 / 3 episodes" in table
    # --resume reads every episode back instead of simulating it again.
    before = (out / "episodes.jsonl").read_text()
    assert evaluate.run(parse("--task", "tool_positioning", "--run-dir", str(run_dir), "--test", "--resume")) == 0
    assert (out / "episodes.jsonl").read_text() == before


def test_bad_input(tmp_path):
    with pytest.raises(InputError, match="run directory .* does not exist"):
        evaluate.run(parse("--run-dir", str(tmp_path / "missing"), "--test"))
    with pytest.raises(InputError, match="at least 1"):
        evaluate.run(parse("--run-dir", str(tmp_path), "--episodes", "0"))
    with pytest.raises(InputError, match="--chain: .*no_such_chain"):
        evaluate.run(parse("--run-dir", str(tmp_path), "--chain", "no_such_chain", "--test"))
    (tmp_path / "feasibility").mkdir()
    config = FeasibilityConfig(history=2, d_model=8, heads=2, layers=1, feedforward=8)
    save_feasibility(tmp_path / "feasibility" / "tool_reorient.pt", build_feasibility_model(160, config), config, 1.0,
                     observation_spec("search", 160), source_task="search", target_task="tool_reorient")
    with pytest.raises(InputError, match="tool_reorient.pt"):
        evaluate.run(parse("--task", "tool_positioning", "--run-dir", str(tmp_path), "--test"))


def test_run_dir_stages_run_the_task_variant_they_were_trained_on(tmp_path):
    """A chain run directory's stage runs its checkpoint's recorded preset (``config.json`` of ``seqdex train``
    beside it, also through a link), else the chain run's ``pipeline.json`` preset, else the paper's."""
    from seqdex_drake.chaining.chain_files import run_dir_configs
    from seqdex_drake.tasks.registry import budget_config, default_config

    trained = tmp_path / "training" / "grasp_run"
    trained.mkdir(parents=True)
    (trained / "last.pt").write_bytes(b"")
    (trained / "config.json").write_text(json.dumps({"task": "grasp", "preset": "budget", "demos": None}))
    stage = tmp_path / "run" / "stages" / "grasp"
    stage.mkdir(parents=True)
    (stage / "last.pt").symlink_to(trained / "last.pt")
    run_dir = tmp_path / "run"
    configs = run_dir_configs(run_dir, ["orient", "grasp"], [None, stage / "last.pt"])
    assert configs == [default_config("orient"), budget_config("grasp")]
    (run_dir / "pipeline.json").write_text(json.dumps({"config": {"preset": "budget"}}))
    assert run_dir_configs(run_dir, ["orient"], [None]) == [budget_config("orient")]


def test_block_goals_are_drawn_at_the_yaws_insert_was_trained_for():
    """The paper's goals are at yaw 0 or 90 deg; the budget Insert is trained at 90 only, and evaluated so."""
    from seqdex_drake.evaluation.episodes import sample_goal
    from seqdex_drake.observation_layout import rotation_matrix

    def yaw(goal):
        R = rotation_matrix(goal[3:])
        return round(float(np.degrees(np.arctan2(R[1, 0], R[0, 0]))))

    rng = np.random.default_rng(0)
    assert {yaw(sample_goal(5, rng)) for _ in range(30)} == {0, 90}
    assert {yaw(sample_goal(5, rng, [90.0])) for _ in range(30)} == {90}


def test_block_episode_records_its_start_and_the_notes_count_distinct_starts():
    """A Building Blocks episode records its (cached pile, block) start; two episodes seeded alike repeat it, and
    the table's notes count the distinct starts (with 8 cached piles, episodes of one type repeat starts)."""
    import types

    from seqdex_drake.evaluation.episodes import handover_notes, run_episode
    from seqdex_drake.evaluation.runner import ChainRunner, RunConfig

    runner = ChainRunner(RunConfig(family="building_blocks", stage_steps=(2,) * 5,
                                   untrained_hidden_sizes=(8,)))
    config = types.SimpleNamespace(family="building_blocks", time_limit=0.05)
    first, _, _ = run_episode(runner, config, 5, seed=0, episode=0, scatter=False)
    again, _, _ = run_episode(runner, config, 5, seed=0, episode=0, scatter=False)
    assert first["start"] == again["start"] and first["start"]["block"].startswith("block_5_")
    assert 0 <= first["start"]["pile"] < 8
    other = dict(first, start={"pile": (first["start"]["pile"] + 1) % 8, "block": "block_5_0"})
    notes = handover_notes("building_blocks", [first, again, other])
    assert "distinct starts (cached pile, block): 2 in 3 episodes" in notes
    assert not any("distinct" in note for note in handover_notes("building_blocks", [{"success": False}]))
