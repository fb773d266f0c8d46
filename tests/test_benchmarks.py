"""The benchmark scripts run end to end (their ``--test`` mode: a few steps each) and print the figures their
issues ask for as the last line's JSON object. Figures are not checked against goals here (timing belongs in
the benchmarks, not in tests); only that they are there and make sense."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(script: str, *args: str) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / script), "--test", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-4000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_env_throughput_reports_the_ratios_and_their_references():
    result = _run("env_throughput.py", "--tasks", "grasp", "tool_grasp", "--envs-per-worker", "2")
    assert set(result["single_process"]) == {"grasp", "tool_grasp"} and not result["failed"]
    assert 0 < result["env_over_raw_min"] == min(r["env_over_raw"] for r in result["single_process"].values())
    assert result["env_over_raw_min_all_tasks"] == result["env_over_raw_min"]  # Both measured tasks are the paper's.
    assert all(r["raw_replays_env_exactly"] for r in result["single_process"].values())  # Same physics timed.
    vector = result["vector"]["grasp"]
    assert result["envs_per_worker"] == 2
    assert result["two_worker_speedup"] == vector["two_worker_speedup_grouped_2_envs_per_worker"]
    assert result["two_worker_speedup_lockstep"] == vector["two_worker_speedup_2_envs_per_worker"]
    assert vector["workers_2_grouped_2_envs_per_worker_steps_per_s"] > 0 and vector["grouped_rollout_horizon"] == 8
    assert vector["two_worker_speedup_1_env_per_worker"] > 0 and result["two_worker_speedup"] > 0
    assert vector["workers_2_2_envs_per_worker_steps_per_s"] > 0
    assert vector["weak_scaling_speedup_2_envs_per_worker"] > 0
    assert set(vector["other_processes_busy_cores"]) == {"1x2", "2x1", "1x4", "2x2", "grouped"}
    assert 1.0 <= vector["sync_bound_speedup"] <= 2.0  # max(t0, t1) lies between the mean and the sum
    assert vector["raw_two_process_speedup"] > 0
    ratio = result["search_over_grasp"]  # Search against Grasp, interleaved, in the same run.
    assert result["search_env_over_grasp_env"] == ratio["search_env_over_grasp_env"] > 0
    assert ratio["search_steps"] > 0 and ratio["grasp_steps"] > 0


def test_chain_runtime_reports_the_tick_its_memory_floor_and_the_real_time_factor():
    result = _run("chain_runtime.py", "--no-meshcat")
    for key in ("tick_ms", "tick_ms_chain", "tick_floor_ms", "memory_bandwidth_gbs", "policy_ms", "feasibility_ms",
                "realtime_factor", "station_realtime_factor"):
        assert result[key] > 0, key
    # The shipped chain's tick when the repository ships one (checkpoints/tool_positioning), else null.
    shipped = (Path(__file__).resolve().parents[1] / "checkpoints" / "tool_positioning" / "manifest.json").is_file()
    assert (result["tick_ms_shipped"] > 0) if shipped else result["tick_ms_shipped"] is None
    assert result["policy_weights_mb"] == pytest.approx(4 * (159 * 1024 + 1024 * 1024 + 1024 * 512 + 512 * 19
                                                             + 1024 + 1024 + 512 + 19) / 1e6, rel=1e-3)
    assert result["realtime_factor_meshcat"] is None  # --no-meshcat


def test_osc_solve_time_reports_the_solves():
    result = _run("osc_solve_time.py")
    assert result["ticks"] > 0 and result["qp_failures"] == 0
    assert 0 < result["osc_solve_ms_p50"] <= result["osc_solve_ms_p99"] <= result["osc_solve_ms_max"]


def test_env_instructions_splits_the_step_into_physics_and_env_code():
    if shutil.which("valgrind") is None:
        pytest.fail("valgrind is not installed; install it with: apt-get install -y valgrind (see .ci/run)")
    result = _run("env_instructions.py")
    counts = result["per_step"]["tool_grasp"]
    assert 0 < counts["outside"] < counts["advance_to"]
    assert abs(counts["total"] - counts["advance_to"] - counts["outside"]) <= 1  # Each rounded per step.
    assert 0 < counts["outside_fraction"] < 0.5 and result["outside_min"] == counts["outside_fraction"]
    # The simulated caches: every last-level (L2-sized) miss is an L1 miss first; some of them are code.
    assert 0 < counts["outside_l2_instruction_misses"] < counts["outside_l2_misses"] <= counts["outside_l1_misses"]
    assert counts["outside_cycles_estimate"] > counts["outside"]


def test_learning_per_sample_trains_both_presets_on_the_same_episodes(tmp_path):
    out = tmp_path / "lps.json"
    result = _run("learning_per_sample.py", "--out", str(out))
    assert result["task"] == "reach" and result["presets_of"] == "tool_grasp"
    budget, paper = result["budget"]["runs"][0], result["paper"]["runs"][0]
    assert budget["env_steps"] >= result["steps"] and paper["env_steps"] >= result["steps"]
    assert budget["model_parameters"] < paper["model_parameters"]  # [256, 256, 128] against [1024, 1024, 512]
    assert 0.0 <= budget["success"] <= 1.0 and len(budget["curve"]) == budget["updates"]
    assert result["budget_minus_paper_success"] == budget["success"] - paper["success"]
    assert result["budget_over_paper_wall_clock"] > 0
    assert json.loads(out.read_text()) == result
    rows = (tmp_path / "lps.csv").read_text().splitlines()
    assert rows[0].startswith("preset,seed,env_steps") and len(rows) == 1 + budget["updates"] + paper["updates"]
    assert (tmp_path / "lps.png").stat().st_size > 0
