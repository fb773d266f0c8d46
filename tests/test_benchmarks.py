"""The benchmark scripts run end to end (their ``--test`` mode: a few steps each) and print the figures their
issues ask for as the last line's JSON object. Figures are not checked against goals here (timing belongs in
the benchmarks, not in tests); only that they are there and make sense.

The benchmarks of docs/performance.md's table run once per session, as ``benchmarks/run_all.py --test`` runs
them (the ``benchmark_run`` fixture of conftest.py); tests/test_docs.py checks the documented keys on the same
runs."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from seqdex_drake.tasks.registry import PAPER_TASKS

ROOT = Path(__file__).resolve().parents[1]


def _run(script: str, *args: str) -> dict:
    """A benchmark that run_all.py does not run (no figure of the docs table), run here."""
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / script), "--test", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-4000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def _result(benchmark_run, name: str) -> dict:
    """The last-line JSON of benchmark ``name``'s shared quick run (see conftest.py)."""
    record = benchmark_run(name)
    assert record["result"] is not None, f"{record['command']} failed (exit {record['exit_code']}):\n" + \
        record.get("error", "")[-4000:]
    return record["result"]


def test_env_throughput_reports_the_ratios_and_their_references(benchmark_run):
    result = _result(benchmark_run, "env_throughput")
    single = result["single_process"]
    assert {"grasp", "tool_grasp", "search"} <= set(single) and not result["failed"]
    paper = [r["env_over_raw"] for name, r in single.items() if name in PAPER_TASKS]
    assert 0 < result["env_over_raw_min"] == min(paper)
    assert result["env_over_raw_min_all_tasks"] == min(r["env_over_raw"] for r in single.values())
    assert result["env_over_raw_min_all_tasks"] <= result["env_over_raw_min"]
    assert all(r["raw_replays_env_exactly"] for r in single.values())  # Same physics timed.
    vector, k = result["vector"]["grasp"], result["envs_per_worker"]
    assert k > 1
    assert result["two_worker_speedup"] == vector[f"two_worker_speedup_grouped_{k}_envs_per_worker"]
    assert result["two_worker_speedup_lockstep"] == vector[f"two_worker_speedup_{k}_envs_per_worker"]
    assert vector[f"workers_2_grouped_{k}_envs_per_worker_steps_per_s"] > 0 and vector["grouped_rollout_horizon"] == 8
    assert vector["two_worker_speedup_1_env_per_worker"] > 0 and result["two_worker_speedup"] > 0
    assert vector[f"workers_2_{k}_envs_per_worker_steps_per_s"] > 0
    assert vector[f"weak_scaling_speedup_{k}_envs_per_worker"] > 0
    assert set(vector["other_processes_busy_cores"]) == {"1x2", "2x1", f"1x{2 * k}", f"2x{k}", f"1x{k}", "grouped"}
    assert 1.0 <= vector["sync_bound_speedup"] <= 2.0  # max(t0, t1) lies between the mean and the sum
    assert vector["raw_two_process_speedup"] > 0
    ratio = result["search_over_grasp"]  # Search against Grasp, interleaved, in the same run.
    assert result["search_env_over_grasp_env"] == ratio["search_env_over_grasp_env"] > 0
    assert ratio["search_steps"] > 0 and ratio["grasp_steps"] > 0


def test_chain_runtime_reports_the_tick_its_memory_floor_and_the_real_time_factor(benchmark_run):
    result = _result(benchmark_run, "chain_runtime")
    for key in ("tick_ms", "tick_ms_chain", "tick_floor_ms", "memory_bandwidth_gbs", "policy_ms", "feasibility_ms",
                "realtime_factor", "station_realtime_factor"):
        assert result[key] > 0, key
    meshcat = result["realtime_factor_meshcat"]  # run_all's test run keeps Meshcat: null where it cannot start.
    assert meshcat is None or meshcat > 0
    # The shipped chain's tick when the repository ships one (checkpoints/tool_positioning), else null.
    shipped = (Path(__file__).resolve().parents[1] / "checkpoints" / "tool_positioning" / "manifest.json").is_file()
    assert (result["tick_ms_shipped"] > 0) if shipped else result["tick_ms_shipped"] is None
    assert (result["tick_ms_shipped_every_tick"] > 0) if shipped else result["tick_ms_shipped_every_tick"] is None
    assert result["policy_weights_mb"] == pytest.approx(4 * (159 * 1024 + 1024 * 1024 + 1024 * 512 + 512 * 19
                                                             + 1024 + 1024 + 512 + 19) / 1e6, rel=1e-3)


def test_main_command_realtime_times_both_shipped_chains_as_the_main_command_runs_them(benchmark_run):
    result = _result(benchmark_run, "main_command_realtime")
    for family in ("building_blocks", "tool_positioning"):
        runs = result[family]
        for run in filter(None, (runs["headless"], runs["meshcat"])):  # Meshcat: null where it cannot start.
            assert run["simulated_s"] == pytest.approx(result["seconds"], abs=1e-6)  # The chain ran the whole span.
            assert run["wall_s"] > 0 and run["realtime_factor"] == pytest.approx(run["simulated_s"] / run["wall_s"],
                                                                                 rel=1e-2)
            assert run["checkpoints"] == "shipped" and run["last_stage"] == 0  # Still in its first stage.
        assert runs["realtime_factor"] == runs["headless"]["realtime_factor"]


def test_osc_solve_time_reports_the_solves(benchmark_run):
    result = _result(benchmark_run, "osc_solve_time")
    assert result["ticks"] > 0 and result["qp_failures"] == 0
    assert 0 < result["osc_solve_ms_p50"] <= result["osc_solve_ms_p99"] <= result["osc_solve_ms_max"]


def test_env_instructions_splits_the_step_into_physics_and_env_code(benchmark_run):
    result = _result(benchmark_run, "env_instructions")  # Fails with how to install valgrind where it is missing.
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
