"""seqdex evaluate --objects (only those objects, in the table and the ablations; bad names list the valid ones)
and --workers (episodes in worker processes, split by seed: the same records, tables and scatter as one process;
a failing or dead worker is a clear error)."""

import csv
import json
import os
import signal

import pytest

from seqdex_drake.chaining.feasibility import FeasibilityConfig, build_feasibility_model
from seqdex_drake.chaining.feasibility_io import save_feasibility
from seqdex_drake.cli.main import main
from seqdex_drake.tasks.run_config import observation_spec

TOOLS = ["evaluate", "--task", "tool_positioning", "--test"]


def _records(out) -> list[dict]:
    records = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    return sorted(records, key=lambda r: (r["experiment"], r["setting"], r["seed"], r["object"], r["episode"]))


def _run_dir(tmp_path, threshold=1e-6, source="tool_grasp"):
    """A run directory with only an untrained F for tool grasp -> tool reorient (a tiny threshold: scores > 1)."""
    run_dir = tmp_path / "run"
    (run_dir / "feasibility").mkdir(parents=True)
    config = FeasibilityConfig(history=3, d_model=16, heads=2, layers=1, feedforward=16)
    save_feasibility(run_dir / "feasibility" / "tool_reorient.pt", build_feasibility_model(159, config), config,
                     threshold, observation_spec(source, 159), source_task=source, target_task="tool_reorient")
    return run_dir


def test_objects_restricts_table_and_ablations(tmp_path, capsys):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    assert main([*TOOLS, "--run-dir", str(run_dir), "--objects", "hammer"]) == 0
    out = run_dir / "evaluation"
    records = _records(out)
    assert {r["object"] for r in records} == {0}
    assert [r["experiment"] for r in records].count("main") == 1 and len(records) == 1 + 4  # + 4 switch caps
    table = (out / "table2_tool_positioning.md").read_text()
    assert "| | hammer | trained | unseen | all |" in table and "spatula" not in table
    row = next(line for line in table.splitlines() if line.startswith("| ours"))
    assert row.split("|")[4].strip() == "-"  # No unseen tool ran: no rate, not 0.
    table_csv = next(csv.DictReader((out / "table2_tool_positioning.csv").open()))
    assert table_csv["unseen_n"] == "0" and table_csv["unseen_mean"] == "" and table_csv["hammer_n"] == "1"
    assert "- objects: hammer;" in (out / "ablation_switching.md").read_text()
    capsys.readouterr()

    assert main([*TOOLS, "--run-dir", str(run_dir), "--objects", "hammer", "hamer"]) == 2
    error = capsys.readouterr().err
    assert "--objects" in error and "'hamer'" in error and "hammer, spatula, spoon" in error
    assert main(["evaluate", "--run-dir", str(run_dir), "--test", "--objects", "9"]) == 2
    assert "1, 2, 3, 4, 5, 6, 7, 8" in capsys.readouterr().err
    assert main([*TOOLS, "--run-dir", str(run_dir), "--workers", "0"]) == 2


def test_workers_give_the_single_process_records(tmp_path):
    run_dir = _run_dir(tmp_path)
    two_seeds = [*TOOLS, "--run-dir", str(run_dir), "--seeds", "2", "--objects", "spoon", "hammer"]
    for workers in (1, 2):
        assert main([*two_seeds, "--workers", str(workers), "--out", str(tmp_path / f"w{workers}")]) == 0
    one, two = _records(tmp_path / "w1"), _records(tmp_path / "w2")
    assert len(one) == 2 * (2 + 4) and {r["seed"] for r in one} == {0, 1} and {r["object"] for r in one} == {0, 2}
    assert one == two  # success, time, errors, switches, stage: all of it
    for name in ("table2_tool_positioning.csv", "ablation_switching.csv", "feasibility_pose_scatter.csv"):
        assert (tmp_path / "w1" / name).read_text() == (tmp_path / "w2" / name).read_text(), name
    points = (tmp_path / "w2" / "feasibility_pose_scatter.csv").read_text().splitlines()[1:]
    ticks = sum(round(r["time"] * 60) for r in two if r["experiment"] == "main")
    assert len(points) == ticks > 0, (len(points), ticks)  # every control tick of the main episodes is scored
    # --resume with workers: nothing left to run, nothing appended.
    before = (tmp_path / "w2" / "episodes.jsonl").read_text()
    assert main([*two_seeds, "--workers", "2", "--resume", "--out", str(tmp_path / "w2")]) == 0
    assert (tmp_path / "w2" / "episodes.jsonl").read_text() == before


def test_worker_errors_reach_the_parent(tmp_path, capsys):
    from seqdex_drake.evaluation.experiments import EvalConfig
    from seqdex_drake.evaluation.parallel import EvaluationWorkerError, WorkerPool

    # A worker's ChainRunError (an F trained on the wrong source task) is the CLI's usual error, exit 2.
    run_dir = _run_dir(tmp_path, threshold=1.0, source="search")
    assert main([*TOOLS, "--run-dir", str(run_dir), "--seeds", "2", "--workers", "2", "--skip-ablations"]) == 2
    assert "tool_reorient.pt" in capsys.readouterr().err
    # A worker that dies is reported, not waited for.
    config = EvalConfig(family="tool_positioning", run_dir=str(run_dir), seeds=(0, 1), workers=2)
    pool = WorkerPool(config)
    os.kill(pool.processes[1].pid, signal.SIGKILL)
    jobs = [dict(experiment="main", setting=3, seed=seed, object=0, episode=0) for seed in (0, 1)]
    with pytest.raises(EvaluationWorkerError, match=r"worker 1 \(seeds \[1\]\) died: killed by signal SIGKILL"):
        pool.run(jobs, {}, False, lambda *_: None)
    assert not pool.processes


def test_workers_exit_when_the_parent_is_killed(tmp_path):
    """A parent killed outright (SIGKILL: no cleanup runs) leaves no worker running on."""
    import subprocess
    import sys
    import time

    run_dir = _run_dir(tmp_path)
    parent = subprocess.Popen([sys.executable, "-m", "seqdex_drake.cli.main", "evaluate", "--task", "tool_positioning",
                               "--run-dir", str(run_dir), "--test", "--seeds", "2", "--episodes", "50", "--workers",
                               "2", "--skip-ablations", "--out", str(tmp_path / "out")],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    records = tmp_path / "out" / "episodes.jsonl"
    deadline = time.monotonic() + 120
    while not (records.is_file() and records.read_text().count("\n") >= 2):  # The workers are running episodes.
        assert time.monotonic() < deadline and parent.poll() is None, "no episode was recorded"
        time.sleep(0.5)
    workers = [int(pid) for pid in subprocess.run(["pgrep", "-P", str(parent.pid)], capture_output=True,
                                                  text=True).stdout.split()]
    assert workers
    parent.kill()
    parent.wait()
    deadline = time.monotonic() + 60
    while any(os.path.exists(f"/proc/{pid}") and "zombie" not in _status(pid) for pid in workers):
        assert time.monotonic() < deadline, "workers outlived their parent"
        time.sleep(0.5)


def _status(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/status") as status:
            return status.read().lower()
    except OSError:
        return "zombie"
