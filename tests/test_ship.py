"""``seqdex pipeline --preset budget --init`` (a chain whose stages were trained before the pipeline) and
``seqdex ship`` (a finished pipeline run as a shipped checkpoint folder)."""

import json
from pathlib import Path

import pytest
import torch
from torch.utils.tensorboard import SummaryWriter

from seqdex_drake.chaining.chain import LoadChain
from seqdex_drake.chaining.chain_files import observation_sizes
from seqdex_drake.chaining.feasibility import FeasibilityConfig, build_feasibility_model
from seqdex_drake.chaining.feasibility_io import save_feasibility
from seqdex_drake.chaining.pipeline import PipelineConfig, RunDirectory
from seqdex_drake.chaining.shipped import load_shipped_chain
from seqdex_drake.cli.main import main
from seqdex_drake.rl.checkpoint import load_checkpoint
from seqdex_drake.rl.config import PPOConfig
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.tasks.run_config import observation_spec

TASKS = ["tool_grasp", "tool_reorient"]
#: The budget variants' observation sizes (both observe their progress).
SIZES = {task: size + 1 for task, size in observation_sizes().items() if task in TASKS}


def _policy(path: Path, task: str, steps: int) -> Path:
    ppo = PPO(PPOConfig(actor_hidden_sizes=(16,), critic_hidden_sizes=(16,), num_envs=1), SIZES[task], 19,
              [-1.0] * 19, [1.0] * 19)
    ppo.obs_spec = observation_spec(task, SIZES[task]).to_dict()
    ppo.global_step = steps
    return ppo.save(path)


def _training_run(directory: Path, task: str, seconds: float) -> Path:
    """A ``seqdex train``-like run directory: its checkpoint and an event file whose updates span ``seconds``."""
    writer = SummaryWriter(str(directory))
    for i, step in enumerate((1000, 2000, 3000)):
        writer.add_scalar("charts/SPS", 1000.0 / (seconds / 3), step, walltime=1000.0 + i * seconds / 3)
        writer.add_scalar("charts/success_rate", 0.1 * i, step, walltime=1000.0 + i * seconds / 3)
    writer.close()
    return _policy(directory / "last.pt", task, 3000)


def _pipeline_run(tmp_path: Path, **overrides) -> Path:
    """A finished tool-positioning pipeline run directory (budget preset, tool Grasp continued from a training run,
    F fitted for tool Reorient), built from its parts."""
    init = _training_run(tmp_path / "grasp_run", "tool_grasp", 3600.0)
    config = PipelineConfig(chain="tool_positioning", preset="budget", init_checkpoints={"tool_grasp": str(init)},
                            **overrides)
    run = RunDirectory(tmp_path / "run", config, LoadChain("tool_positioning"), resume=False)
    for task, steps in zip(TASKS, (5000, 800), strict=True):
        _policy(run.policy(task), task, steps)
    feasibility = FeasibilityConfig(history=10, epochs=1)
    model = build_feasibility_model(SIZES["tool_grasp"], feasibility)
    save_feasibility(run.feasibility("tool_reorient"), model, feasibility, 12.5,
                     observation_spec("tool_grasp", SIZES["tool_grasp"]), source_task="tool_grasp",
                     target_task="tool_reorient")
    for phase, seconds in (("forward_0_tool_grasp", 10.0), ("forward_1_tool_reorient", 20.0),
                           ("buffer_0_tool_grasp", 100.0), ("finetune_1_tool_grasp", 300.0)):
        run.finish(phase, {"steps": 0, "seconds": seconds})
    run.write_results({"wall_clock_s": 430.0, "ppo_steps": 2000, "success_rate": 0.25, "success_rate_switcher": 0.3})
    return run.root


def test_ship_writes_a_folder_that_loads_with_training_costs_and_its_f(tmp_path, capsys):
    run_dir = _pipeline_run(tmp_path)
    out = tmp_path / "checkpoints" / "tool_positioning"
    assert main(["ship", "--run-dir", str(run_dir), "--out", str(out)]) == 0
    chain = load_shipped_chain(out, "tool_positioning", TASKS, observation_sizes())
    assert chain.missing == [] and chain.feasibility[0] is None
    assert chain.feasibility[1] == out / "feasibility" / "tool_reorient.pt"
    stages = chain.manifest["stages"]
    # tool Grasp: its training run (3600 s of updates) + its pipeline phases (forward 10 s, fine-tuning 300 s).
    assert stages["tool_grasp"]["wall_clock_s"] == pytest.approx(3600.0 + 310.0, rel=1e-3)
    assert stages["tool_grasp"]["core_hours"] == pytest.approx(2 * 3910.0 / 3600, rel=1e-3)
    assert stages["tool_reorient"]["wall_clock_s"] == pytest.approx(20.0)
    assert (stages["tool_grasp"]["env_steps"], stages["tool_reorient"]["env_steps"]) == (5000, 800)
    assert chain.manifest["pipeline"]["method"] == "seqdex" and chain.manifest["pipeline"]["success_rate"] == 0.25
    assert "3910" not in capsys.readouterr().err
    # The shipped policies are the run's for inference: its weights, without the optimizer's moments; the F is the
    # run's, byte for byte.
    shipped, trained = (load_checkpoint(path) for path in (out / "stages" / "tool_grasp" / "best.pt",
                                                           run_dir / "stages" / "tool_grasp" / "last.pt"))
    assert shipped["optimizer"]["state"] == {} and shipped["counters"] == trained["counters"]
    for key, value in trained["model"].items():
        assert torch.allclose(shipped["model"][key], value, rtol=0, atol=0, equal_nan=True), key
    assert (out / "feasibility" / "tool_reorient.pt").read_bytes() == \
        (run_dir / "feasibility" / "tool_reorient.pt").read_bytes()
    # An existing folder is kept unless --force.
    assert main(["ship", "--run-dir", str(run_dir), "--out", str(out)]) == 2
    assert "already exists; pass --force" in capsys.readouterr().err
    assert main(["ship", "--run-dir", str(run_dir), "--out", str(out), "--force"]) == 0
    assert not list(out.parent.glob(".tool_positioning*"))  # No staging folder left behind.


def test_ship_refuses_unfinished_test_and_missing_runs(tmp_path, capsys):
    assert main(["ship", "--run-dir", str(tmp_path / "nothing"), "--out", str(tmp_path / "o")]) == 2
    assert "holds no pipeline run" in capsys.readouterr().err
    run_dir = _pipeline_run(tmp_path / "a")
    (run_dir / "results.json").unlink()
    assert main(["ship", "--run-dir", str(run_dir), "--out", str(tmp_path / "o")]) == 2
    assert "has not finished" in capsys.readouterr().err
    test_run = _pipeline_run(tmp_path / "b", episode_length_cap=6)
    assert main(["ship", "--run-dir", str(test_run), "--out", str(tmp_path / "o")]) == 2
    assert "is a --test run" in capsys.readouterr().err
    run_dir = _pipeline_run(tmp_path / "c")
    (run_dir / "stages" / "tool_reorient" / "last.pt").unlink()
    assert main(["ship", "--run-dir", str(run_dir), "--out", str(tmp_path / "o")]) == 2
    assert "stage tool_reorient has not been trained" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_pipeline_continues_each_stage_from_its_init_checkpoint(tmp_path, capsys):
    runs = {}
    for task in ("reach", "lower"):
        runs[task] = tmp_path / task
        assert main(["train", "--task", task, "--test", "--preset", "budget", "--run-dir", str(runs[task])]) == 0
    init = [f"--init={task}={runs[task] / 'last.pt'}" for task in runs]
    run_dir = tmp_path / "pipeline"
    # Another task's checkpoint for a stage is refused before any training.
    wrong = ["--init", f"reach={runs['lower'] / 'last.pt'}", "--init", f"lower={runs['lower'] / 'last.pt'}"]
    assert main(["pipeline", "--chain", "handover", "--test", "--preset", "budget", *wrong, "--stage-steps", "0",
                 "--run-dir", str(tmp_path / "wrong")]) == 2
    assert "another task's policy" in capsys.readouterr().err
    assert main(["pipeline", "--chain", "handover", "--test", "--init", f"reach={runs['reach'] / 'last.pt'}",
                 "--stage-steps", "0", "--run-dir", str(tmp_path / "half")]) == 2
    assert "leaves the stages without --init untrained (lower)" in capsys.readouterr().err
    assert main(["pipeline", "--chain", "handover", "--test", "--preset", "budget", *init, "--stage-steps", "0",
                 "--run-dir", str(run_dir)]) == 0
    record = json.loads((run_dir / "pipeline.json").read_text())
    assert record["config"]["preset"] == "budget"
    assert record["config"]["init_checkpoints"] == {task: str(runs[task] / "last.pt") for task in runs}
    for i, task in enumerate(runs):
        before = load_checkpoint(runs[task] / "last.pt", map_location="cpu")
        after = load_checkpoint(run_dir / "phases" / f"forward_{i}_{task}" / "last.pt", map_location="cpu")
        # Zero forward steps: the stage's forward policy is its init checkpoint's (weights and step count).
        assert after["counters"]["global_step"] == before["counters"]["global_step"]
        for key, value in before["model"].items():
            assert torch.allclose(after["model"][key], value, rtol=0, atol=0, equal_nan=True), key
    # The backward fine-tuning then continues tool Grasp's (here: Reach's) init policy.
    finetuned = load_checkpoint(run_dir / "stages" / "reach" / "last.pt", map_location="cpu")
    assert finetuned["counters"]["global_step"] > load_checkpoint(runs["reach"] / "last.pt")["counters"]["global_step"]
