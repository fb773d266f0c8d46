"""The bi-directional pipeline end to end on the hand-over chain: every method under ``--test`` (a tiny budget),
resume, the feasibility and finetune subcommands, the chain env, and bad input. Everything runs in this process
(the serial backend), so the stations are built once and shared by all runs."""

import dataclasses
import json

import numpy as np
import pytest

from seqdex_drake.chaining.pipeline import METHODS, pipeline_budget
from seqdex_drake.cli.main import main


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Every method's ``seqdex pipeline --test`` run directory."""
    root = tmp_path_factory.mktemp("pipelines")
    for method in METHODS:
        code = main(["pipeline", "--chain", "handover", "--method", method, "--test", "--run-dir",
                     str(root / method)])
        assert code == 0, method
    return root


@pytest.mark.parametrize("method", METHODS)
def test_every_method_runs_end_to_end_on_the_same_budget(runs, method):
    results = json.loads((runs / method / "results.json").read_text())
    assert results["method"] == method and results["stages"] == ["reach", "lower"]
    assert results["ppo_steps"] == results["ppo_budget"] == 2 * 64 + 32  # K stage_steps + (K-1) finetune_steps
    assert 0.0 <= results["success_rate"] <= 1.0
    phases = results["phases"]
    if method in ("scratch", "curriculum"):
        assert not (runs / method / "stages").exists()  # One policy over the whole chain.
        assert sum(p["steps"] for p in phases.values()) == results["ppo_budget"]
        if method == "curriculum":
            assert [p["start_stage"] for p in phases.values()] == [1, 0]  # From the last stage back.
    else:
        for task in ("reach", "lower"):
            assert (runs / method / "stages" / task / "last.pt").is_file()
        assert (runs / method / "buffers" / "reach_to_lower.npz").is_file()
        assert "finetune_1_reach" in phases
    if method in ("seqdex", "seqdex_no_temporal"):
        from seqdex_drake.chaining.feasibility_io import load_feasibility

        f = load_feasibility(runs / method / "feasibility" / "lower.pt")
        assert f.source_task == "reach" and f.target_task == "lower" and f.threshold > 0
        assert f.config.temporal == (method == "seqdex")
        assert results["success_rate_switcher"] is not None
    if method == "tstar":
        assert (runs / method / "tstar" / "lower.pt").is_file()


def test_resume_skips_finished_phases_and_reproduces_the_results(runs, capsys):
    before = json.loads((runs / "seqdex" / "results.json").read_text())
    assert main(["pipeline", "--chain", "handover", "--method", "seqdex", "--test", "--resume", "--run-dir",
                 str(runs / "seqdex"), "--envs-per-worker", "2"]) == 0  # A layout change is no config change.
    after = json.loads((runs / "seqdex" / "results.json").read_text())
    assert after["phases"] == before["phases"] and after["success_rate"] == before["success_rate"]
    assert after["evaluation"] == before["evaluation"]


def test_same_seed_gives_the_same_run(runs, tmp_path):
    assert main(["pipeline", "--chain", "handover", "--method", "policy_seq", "--test", "--run-dir",
                 str(tmp_path / "again")]) == 0
    first = json.loads((runs / "policy_seq" / "results.json").read_text())
    second = json.loads((tmp_path / "again" / "results.json").read_text())
    assert first["evaluation"] == second["evaluation"]
    for phase in ("forward_0_reach", "forward_1_lower", "finetune_1_reach"):
        assert first["phases"][phase]["success_rate"] == second["phases"][phase]["success_rate"] or \
            np.isnan(first["phases"][phase]["success_rate"])


def test_feasibility_subcommand_writes_the_history_ablation(runs, capsys):
    assert main(["feasibility", "--run-dir", str(runs / "seqdex"), "--task", "lower", "--history", "5"]) == 0
    from seqdex_drake.chaining.feasibility_io import load_feasibility

    assert load_feasibility(runs / "seqdex" / "feasibility" / "lower_h5.pt").config.history == 5
    assert main(["feasibility", "--run-dir", str(runs / "seqdex"), "--task", "reach"]) == 2
    assert "first stage" in capsys.readouterr().err


def test_feasibility_subcommand_sets_the_architecture(runs, tmp_path, capsys):
    from seqdex_drake.chaining.feasibility_io import load_feasibility

    out = tmp_path / "slim.pt"
    assert main(["feasibility", "--run-dir", str(runs / "seqdex"), "--task", "lower", "--layers", "1",
                 "--d-model", "32", "--heads", "2", "--feedforward", "48", "--out", str(out)]) == 0
    model = load_feasibility(out).model
    assert (model.config.layers, model.config.d_model, model.config.heads) == (1, 32, 2)
    assert len(model.encoder.layers) == 1 and model.encoder.layers[0].linear1.out_features == 48
    record = json.loads((runs / "seqdex" / "pipeline.json").read_text())["done"]["feasibility_cli_lower_h10"]
    assert (record["layers"], record["d_model"], record["out"]) == (1, 32, str(out))
    for bad, message in ((["--heads", "3"], "must divide"), (["--layers", "0"], ">= 1")):
        assert main(["feasibility", "--run-dir", str(runs / "seqdex"), "--task", "lower", *bad]) == 2
        assert message in capsys.readouterr().err


def test_feasibility_subcommand_recollects_with_a_stage_on_another_scene(runs, tmp_path, capsys):
    from seqdex_drake.chaining.stage_envs import _ENV_POOL

    run = str(runs / "seqdex")
    assert main(["feasibility", "--run-dir", run, "--task", "lower", "--recollect", "--scene", "lower=handover/reach",
                 "--out", str(tmp_path / "lower_on_reach.pt")]) == 0
    done = json.loads((runs / "seqdex" / "pipeline.json").read_text())["done"]
    assert done["feasibility_cli_lower_h10"]["scenes"] == {"lower": "handover/reach"}
    assert done["transitions_recollect_lower_i0_lower@handover-reach"]["episodes"] > 0
    # The collection's Lower env was built on the Reach scene.
    assert any(task == "lower" and "scenario='handover/reach'" in config for task, config, _ in _ENV_POOL)
    for bad, message in ((["--scene", "lower=handover/reach"], "needs --recollect"),
                         (["--recollect", "--scene", "lower=handover/nope"], "does not load"),
                         (["--recollect", "--scene", "grasp=handover/reach"], "not a stage"),
                         (["--recollect", "--scene", "lower"], "expected TASK=SCENARIO"),
                         (["--recollect", "--scene", "lower=handover/reach", "--scene", "lower=handover/lower"],
                          "twice")):
        assert main(["feasibility", "--run-dir", run, "--task", "lower", *bad]) == 2
        assert message in capsys.readouterr().err


def test_feasibility_subcommand_reports_transitions_that_cannot_define_f(runs, tmp_path, monkeypatch, capsys):
    """Transitions whose successful returns give no positive threshold h: exit 1 with the reason, no traceback,
    no F written, the transitions kept."""
    import seqdex_drake.chaining.bidirectional as bidirectional

    transitions = runs / "seqdex" / "transitions" / "lower.npz"
    before = transitions.read_bytes()
    with np.load(transitions) as data:
        shifted = {key: data[key] for key in data.files}
    shifted["returns"] = shifted["returns"] - shifted["returns"].max() - 1.0  # Every return negative ...
    shifted["successes"] = np.ones_like(shifted["successes"])  # ... successes' included.
    monkeypatch.setattr(bidirectional.Pipeline, "transition_data", lambda self, index: shifted)
    out = tmp_path / "never.pt"
    assert main(["feasibility", "--run-dir", str(runs / "seqdex"), "--task", "lower", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "cannot be fitted" in err and "is not positive" in err and "Traceback" not in err
    assert not out.exists() and transitions.read_bytes() == before


def test_feasibility_subcommand_fits_the_success_label_where_returns_cannot(runs, tmp_path, monkeypatch, capsys):
    """Successful returns all negative (Orient in the pile): the return label cannot set h, the success label
    can (h = 0.5), and --folds reports the out-of-fold AUC and R^2 on the record."""
    import seqdex_drake.chaining.bidirectional as bidirectional
    from seqdex_drake.chaining.feasibility_io import load_feasibility

    with np.load(runs / "seqdex" / "transitions" / "lower.npz") as data:
        shifted = {key: data[key] for key in data.files}
    count = len(shifted["returns"])
    shifted["successes"] = np.arange(count) % 2 == 0
    shifted["returns"] = np.where(shifted["successes"], -5.0, 1.0)
    monkeypatch.setattr(bidirectional.Pipeline, "transition_data", lambda self, index: shifted)
    out = tmp_path / "success.pt"
    assert main(["feasibility", "--run-dir", str(runs / "seqdex"), "--task", "lower", "--out", str(out)]) == 1
    capsys.readouterr()
    assert main(["feasibility", "--run-dir", str(runs / "seqdex"), "--task", "lower", "--label", "success",
                 "--folds", "2", "--out", str(out)]) == 0
    assert "success label" in capsys.readouterr().out
    f = load_feasibility(out)
    assert (f.config.label, f.threshold) == ("success", 0.5) and "cv_auc" in f.metrics
    record = json.loads((runs / "seqdex" / "pipeline.json").read_text())["done"]["feasibility_cli_lower_h10"]
    assert record["label"] == "success" and record["cv_folds"] == 2 and record["cv_n"] == count
    for bad, message in ((["--folds", "1"], "--folds"),):
        assert main(["feasibility", "--run-dir", str(runs / "seqdex"), "--task", "lower", *bad]) == 2
        assert message in capsys.readouterr().err


def test_finetune_subcommand_continues_a_run(runs, capsys):
    assert main(["finetune", "--run-dir", str(runs / "tstar")]) == 0
    assert "chain success" in capsys.readouterr().out
    assert main(["finetune", "--run-dir", str(runs / "scratch")]) == 2


def test_bad_input(runs, tmp_path, capsys):
    with pytest.raises(SystemExit) as error:  # argparse lists the valid chains and methods.
        main(["pipeline", "--chain", "nope", "--test"])
    assert error.value.code == 2
    assert main(["pipeline", "--chain", "handover", "--test", "--run-dir", str(runs / "seqdex")]) == 2
    assert "already holds a pipeline run" in capsys.readouterr().err
    assert main(["pipeline", "--chain", "handover", "--method", "vchain", "--test", "--resume", "--run-dir",
                 str(runs / "seqdex")]) == 2
    assert "another configuration" in capsys.readouterr().err
    assert main(["pipeline", "--chain", "handover", "--test", "--envs-per-worker", "0", "--run-dir",
                 str(tmp_path / "zero")]) == 2
    assert "--envs-per-worker must be >= 1" in capsys.readouterr().err
    assert main(["finetune", "--run-dir", str(tmp_path / "missing")]) == 2
    assert "holds no pipeline run" in capsys.readouterr().err
    present = str(runs / "seqdex" / "stages" / "reach" / "last.pt")
    for init, message in ((["reach"], "expected TASK=CHECKPOINT"),
                          ([f"reach={present}", f"reach={present}"], "names reach twice"),
                          ([f"reach={tmp_path / 'none.pt'}"], "does not exist")):
        flags = [flag for value in init for flag in ("--init", value)]
        assert main(["pipeline", "--chain", "handover", "--test", *flags, "--run-dir", str(tmp_path / "bad")]) == 2
        assert message in capsys.readouterr().err


def test_budget_formula():
    from seqdex_drake.chaining.pipeline import PipelineConfig

    assert pipeline_budget(PipelineConfig(stage_steps=10, finetune_steps=3, iterations=2), 4) == 4 * 10 + 3 * 3 * 3


def test_a_second_pass_runs_the_forward_step_again_then_fine_tunes(tmp_path):
    """Algorithm 1 with M = 2: pass 2 re-collects rho_lower from the fine-tuned Reach, trains Lower further on it,
    then fine-tunes Reach again with a refitted F; the budget counts every phase."""
    assert main(["pipeline", "--chain", "handover", "--method", "seqdex", "--test", "--iterations", "2",
                 "--run-dir", str(tmp_path / "m2")]) == 0
    results = json.loads((tmp_path / "m2" / "results.json").read_text())
    order = [phase for phase in results["phases"] if not phase.startswith(("transitions_", "bonus_"))]
    assert order == ["forward_0_reach", "buffer_0_reach", "forward_1_lower", "finetune_1_reach", "buffer_1_reach",
                     "reforward_2_lower", "finetune_2_reach"]
    assert results["ppo_steps"] == results["ppo_budget"] == 2 * 64 + 3 * 32
    assert results["phases"]["reforward_2_lower"]["steps"] == 32
    assert "bonus_2_lower" in results["phases"] and "transitions_bonus_2_lower" in results["phases"]


def test_chain_env_hands_over_at_each_stage_budget():
    from seqdex_drake.cli.main import main as _  # noqa: F401 (import order as in the CLI)
    from seqdex_drake.envs.chain_env import ChainEnv

    env = ChainEnv(["reach", "lower"])
    observation, info = env.reset(seed=3)
    assert observation.shape == (159 + 2,) and observation[159] == 1 and info["stage"] == 0
    for step in range(1, 46):  # Reach 30 steps, Lower 15.
        observation, reward, terminated, truncated, info = env.step(np.zeros(19))
        assert np.isfinite(reward) and not terminated
        if step == 30:
            assert info["handover"] and observation[160] == 1 and observation[159] == 0
        assert truncated == (step == 45)
    assert info["stage"] == 1 and isinstance(info["success"], bool)
    observation, info = env.reset(seed=3, options={"start_stage": 1})
    assert info["stage"] == 1 and observation[160] == 1


def test_tstar_without_positive_examples_pays_no_transition_reward(runs, tmp_path):
    """When no Lower execution succeeded from Reach's hand-overs the discriminator has nothing to separate: T-STAR
    then fine-tunes on Reach's own reward (a zero bonus, logged) instead of failing the whole comparison."""
    import shutil

    from seqdex_drake.chaining.bidirectional import Pipeline

    run_dir = tmp_path / "tstar"
    shutil.copytree(runs / "tstar", run_dir)
    record = json.loads((run_dir / "pipeline.json").read_text())
    del record["done"]["bonus_1_lower"]
    (run_dir / "pipeline.json").write_text(json.dumps(record))
    with np.load(run_dir / "transitions" / "lower.npz") as data:
        arrays = {key: data[key] for key in data.files}
    arrays["successes"][:] = False
    np.savez(run_dir / "transitions" / "lower.npz", **arrays)
    pipeline = Pipeline.open(run_dir, log=lambda message: None)
    pipeline.config = dataclasses.replace(pipeline.config, handoff_failures=False)
    bonus = pipeline.transition_bonus("bonus_1_lower", 1)
    assert bonus(arrays["histories"][0]) == 0.0
    assert not (run_dir / "tstar" / "lower.pt").exists()
    assert json.loads((run_dir / "pipeline.json").read_text())["done"]["bonus_1_lower"]["positives"] == 0
