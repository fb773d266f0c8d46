"""The ``seqdex`` command line: train, resume, collect and the error paths, end to end on the grasp sub-task.

Everything runs with ``--test`` (episodes of a few steps, 64-64 networks, one PPO update per call).
"""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from seqdex_drake.chaining.terminal_buffer import TerminalBuffer
from seqdex_drake.cli.main import main
from seqdex_drake.cli.train import TEST_HORIZON
from seqdex_drake.tasks.registry import task_names
from seqdex_drake.tasks.run_config import TEST_EPISODE_LENGTH, observation_spec, task_config

ROOT = Path(__file__).resolve().parents[1]


def _steps(path) -> int:
    return torch.load(path, weights_only=True)["counters"]["global_step"]


@pytest.fixture(scope="module")
def grasp_run(tmp_path_factory):
    """A grasp run directory after ``seqdex train --task grasp --test --preset paper`` (two envs, one update)."""
    run_dir = tmp_path_factory.mktemp("cli") / "grasp"
    assert main(["train", "--task", "grasp", "--test", "--run-dir", str(run_dir), "--num-envs", "2",
                 "--preset", "paper"]) == 0
    return run_dir


def test_train_writes_run_directory(grasp_run):
    assert (grasp_run / "last.pt").is_file()
    assert _steps(grasp_run / "last.pt") == 16  # 2 envs x horizon 8.
    record = json.loads((grasp_run / "config.json").read_text())
    assert record["task"] == "grasp" and record["test"] is True and record["initial_states"] is None
    assert record["ppo"]["gamma"] == 0.9 and record["ppo"]["num_envs"] == 2  # Paper's grasp column.
    assert record["task_config"]["episode_length"] == TEST_EPISODE_LENGTH
    assert "building_blocks" in (grasp_run / "scenario.yaml").read_text()
    assert list(grasp_run.glob("events.out.tfevents.*")), "no TensorBoard log"


def test_resume_continues_counters(grasp_run, tmp_path, capsys):
    run_dir = tmp_path / "resumed"
    shutil.copytree(grasp_run, run_dir)
    before = torch.load(run_dir / "last.pt", weights_only=True)["counters"]
    assert main(["train", "--task", "grasp", "--test", "--run-dir", str(run_dir), "--resume",
                 "--envs-per-worker", "2"]) == 0  # Both envs in one process now: the layout is free to change.
    after = torch.load(run_dir / "last.pt", weights_only=True)["counters"]
    assert after["global_step"] == before["global_step"] + 16
    assert after["num_updates"] == before["num_updates"] + 1
    assert "steps 16 -> 32" in capsys.readouterr().out
    # Starting afresh over an existing run is refused; so is resuming with another task config.
    assert main(["train", "--task", "grasp", "--test", "--run-dir", str(run_dir)]) == 2
    assert "--resume" in capsys.readouterr().err
    assert main(["train", "--task", "grasp", "--run-dir", str(run_dir), "--resume"]) == 2
    assert "task config differs" in capsys.readouterr().err
    assert _steps(run_dir / "last.pt") == 32
    assert main(["train", "--task", "grasp", "--test", "--run-dir", str(run_dir), "--resume",
                 "--envs-per-worker", "0"]) == 2
    assert "--envs-per-worker must be >= 1" in capsys.readouterr().err


def test_collect_writes_loadable_buffer(grasp_run, tmp_path, capsys):
    out = tmp_path / "grasp_to_insert.npz"
    args = ["collect", "--task", "grasp", "--test", "--checkpoint", str(grasp_run / "last.pt"), "--out", str(out)]
    assert main(args) == 0
    printed = capsys.readouterr().out
    successes = int(printed.split(" successes out of 2 ")[0].split()[-1])
    buffer = TerminalBuffer.load(out, expected_task="insert", expected_source="grasp")
    assert len(buffer) == successes and buffer.successes.all()  # An untrained policy may have none: empty file.
    assert buffer.history == 10 and buffer.obs_spec.dim == 159
    if successes == 0:
        assert "no successful episode" in printed
    # --keep-failures --resume appends every episode to the same file.
    assert main(args + ["--keep-failures", "--resume", "--seed", "5"]) == 0
    capsys.readouterr()
    buffer = TerminalBuffer.load(out, expected_task="insert")
    assert len(buffer) == 2 * successes + (2 - successes)
    assert buffer.histories.shape == (len(buffer), 10, 159) and np.isfinite(buffer.returns).all()


def test_collect_keeps_the_real_successes_of_a_trained_policy_and_only_those(tmp_path, capsys):
    """Forward initialization's success filter with successes that happen: the shipped Orient policy stands up 5 of
    the 6 blocks of seed 0. The buffer keeps those 5, each ending upright (the block's z axis within Orient's
    success test of world z); ``--keep-failures`` adds all 6, the one failure flagged and not upright."""
    from seqdex_drake.observation_layout import OBJECT_QUATERNION

    def upright(histories):
        _, x, y, _ = histories[:, -1, OBJECT_QUATERNION].T
        return 1.0 - 2.0 * (x * x + y * y) > 0.6

    shipped = ROOT / "checkpoints" / "building_blocks" / "stages" / "orient" / "best.pt"
    out = tmp_path / "orient_to_grasp.npz"
    args = ["collect", "--task", "orient", "--checkpoint", str(shipped), "--preset", "budget", "--episodes", "6",
            "--seed", "0", "--out", str(out)]
    assert main(args) == 0
    assert "5 successes out of 6 orient episodes" in capsys.readouterr().out
    buffer = TerminalBuffer.load(out, expected_task="grasp", expected_source="orient")
    assert len(buffer) == 5 and buffer.successes.all() and upright(buffer.histories).all()
    assert main(args + ["--keep-failures", "--resume"]) == 0
    buffer = TerminalBuffer.load(out, expected_task="grasp")
    assert len(buffer) == 11 and buffer.successes.sum() == 10
    assert np.array_equal(upright(buffer.histories), buffer.successes)


def test_collect_takes_the_preset_of_a_checkpoint_without_its_run_record(tmp_path, capsys):
    """A shipped stage checkpoint (``checkpoints/<family>/stages/<task>/best.pt``) has no config.json beside it:
    the budget variant's policy (160 observations for grasp) is refused for the paper env with a hint to
    ``--preset``, and collects with ``--preset budget``."""
    run_dir = tmp_path / "run"
    assert main(["train", "--task", "grasp", "--test", "--run-dir", str(run_dir), "--num-envs", "2",
                 "--preset", "budget"]) == 0
    shipped = tmp_path / "stages" / "grasp" / "best.pt"
    shipped.parent.mkdir(parents=True)
    shutil.copy(run_dir / "last.pt", shipped)
    capsys.readouterr()
    out = tmp_path / "buffer.npz"
    args = ["collect", "--task", "grasp", "--test", "--checkpoint", str(shipped), "--out", str(out)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "160 observations" in err and "--preset" in err and "Traceback" not in err and not out.exists()
    assert main(args + ["--preset", "budget"]) == 0
    assert TerminalBuffer.load(out, expected_task="insert").obs_spec.dim == 160


def test_collect_refuses_last_task_and_missing_checkpoint(tmp_path, capsys):
    assert main(["collect", "--task", "insert", "--test", "--run-dir", str(tmp_path)]) == 2
    assert "last sub-task" in capsys.readouterr().err
    missing = tmp_path / "nothing" / "last.pt"
    assert main(["collect", "--task", "grasp", "--test", "--checkpoint", str(missing)]) == 2
    err = capsys.readouterr().err
    assert str(missing) in err and "does not exist" in err and "Traceback" not in err
    assert not list(tmp_path.glob("**/*.npz"))


def test_resume_without_checkpoint_is_a_clear_error(tmp_path, capsys):
    assert main(["train", "--task", "grasp", "--test", "--run-dir", str(tmp_path / "none"), "--resume"]) == 2
    err = capsys.readouterr().err
    assert "no checkpoint" in err and "without --resume" in err and "Traceback" not in err


def test_unknown_task_exits_2_listing_tasks(tmp_path):
    result = subprocess.run([sys.executable, "-m", "seqdex_drake.cli.main", "train", "--task", "juggle", "--test",
                             "--run-dir", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert "Traceback" not in result.stderr and "juggle" in result.stderr
    assert all(name in result.stderr for name in task_names())


def _tool_grasp_buffer(path):
    """A one-entry tool_grasp -> tool_reorient buffer holding a tool_grasp env state a few steps after reset."""
    from seqdex_drake.envs.subtask_env import make_env

    env = make_env("tool_grasp", task_config("tool_grasp", True))
    observation, _ = env.reset(seed=3)
    observations = [observation] + [env.step(np.zeros(19))[0] for _ in range(10)]
    buffer = TerminalBuffer("tool_grasp", "tool_reorient", env.config.scenario,
                            observation_spec("tool_grasp", observation.size), 10)
    state = env.get_state()
    buffer.append(state, np.stack(observations), 1.0, True)
    buffer.save(path)
    return state


def test_initial_states_restart_every_episode(tmp_path):
    from seqdex_drake.cli.train import InitialStateVectorEnv, load_initial_states
    from seqdex_drake.envs.vector import ProcessVectorEnv

    state = _tool_grasp_buffer(tmp_path / "tool.npz")
    buffer = load_initial_states(str(tmp_path / "tool.npz"), "tool_reorient")
    with ProcessVectorEnv("tool_reorient", 1, seed=0, config=task_config("tool_reorient", True)) as inner:
        env = InitialStateVectorEnv(inner, buffer, seed=0)
        env.reset(seed=0)
        np.testing.assert_allclose(inner.get_states()[0].plant_positions, state.plant_positions)
        for step in range(TEST_EPISODE_LENGTH):
            _, _, terminated, truncated, infos = env.step(np.zeros((1, 19)))
            if step < TEST_EPISODE_LENGTH - 1:
                assert not np.any(terminated | truncated)
                assert not np.allclose(inner.get_states()[0].plant_positions, state.plant_positions)
        assert truncated[0] and "final_observation" in infos[0]
        np.testing.assert_allclose(inner.get_states()[0].plant_positions, state.plant_positions)


def test_train_with_initial_states(tmp_path, capsys):
    buffer = str(tmp_path / "tool.npz")
    _tool_grasp_buffer(buffer)
    run_dir = tmp_path / "reorient_fi"
    assert main(["train", "--task", "tool_reorient", "--test", "--run-dir", str(run_dir), "--initial-states",
                 buffer]) == 0
    assert json.loads((run_dir / "config.json").read_text())["initial_states"] == buffer
    assert _steps(run_dir / "last.pt") == 2 * TEST_HORIZON
    # A buffer for another task, a missing one (names the collect command), a first task of a chain.
    assert main(["train", "--task", "orient", "--test", "--run-dir", str(tmp_path / "o"), "--initial-states",
                 buffer]) == 2
    assert "target task 'tool_reorient'" in capsys.readouterr().err
    assert main(["train", "--task", "insert", "--test", "--run-dir", str(tmp_path / "i"), "--initial-states",
                 str(tmp_path / "missing.npz")]) == 2
    assert "seqdex collect --task grasp" in capsys.readouterr().err
    assert main(["train", "--task", "search", "--test", "--run-dir", str(tmp_path / "s"), "--initial-states",
                 buffer]) == 2
    assert "first sub-task" in capsys.readouterr().err


def test_train_from_hand_offs_saved_on_another_scene(tmp_path, capsys):
    """Insert trains on its boards from Grasp's states, saved in the box (another plant size): the hand-off carries
    the robot and the block over. A state without those fields is refused before training, saying why."""
    import dataclasses

    from seqdex_drake.envs.subtask_env import make_env

    env = make_env("grasp", task_config("grasp", True))
    observation, _ = env.reset(seed=3)
    observations = [observation] + [env.step(np.zeros(19))[0] for _ in range(10)]
    state = env.get_state()
    for name, saved in (("carried.npz", state), ("bare.npz", dataclasses.replace(state, robot_positions=np.zeros(0)))):
        buffer = TerminalBuffer("grasp", "insert", env.config.scenario, observation_spec("grasp", observation.size),
                                10)
        buffer.append(saved, np.stack(observations), 1.0, True)
        buffer.save(tmp_path / name)
    args = ["train", "--task", "insert", "--test", "--preset", "paper", "--initial-states"]
    assert main(args + [str(tmp_path / "carried.npz"), "--run-dir", str(tmp_path / "carried")]) == 0
    assert _steps(tmp_path / "carried" / "last.pt") == 2 * TEST_HORIZON
    capsys.readouterr()
    assert main(args + [str(tmp_path / "bare.npz"), "--run-dir", str(tmp_path / "bare")]) == 2
    err = capsys.readouterr().err
    assert "grasp states" in err and "lacks the robot and target fields" in err and "Traceback" not in err
    assert not (tmp_path / "bare" / "last.pt").exists()


def test_rollout_from_a_hand_off_buffer(tmp_path, capsys):
    buffer, out = str(tmp_path / "tool.npz"), tmp_path / "rollout.json"
    state = _tool_grasp_buffer(buffer)
    assert main(["rollout", "--task", "tool_reorient", "--zero-action", "--test", "--episodes", "2",
                 "--initial-states", buffer, "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["initial_states"] == buffer and len(result["per_episode"]) == 2
    # The episodes start from the buffer's hand-off (not from the standalone fist grasp) ...
    from seqdex_drake.envs.subtask_env import make_env
    from seqdex_drake.evaluation.subtask_episodes import run_episode

    env = make_env("tool_reorient", task_config("tool_reorient", True, "budget"))
    starts = []
    run_episode(env, lambda observation: starts.append(env.object_pose().translation()) or np.zeros(19), 0, state)
    assert abs(starts[0][2] - 0.6) < 0.1  # The hand-off's tool lies on the table; the fist grasp holds it at 1.1 m.
    # ... and a buffer of another hand-off is refused before any rollout.
    capsys.readouterr()
    assert main(["rollout", "--task", "insert", "--zero-action", "--test", "--initial-states", buffer]) == 2
    assert "target task 'tool_reorient'" in capsys.readouterr().err


def test_rollout_of_chosen_objects_records_each_episodes_object(tmp_path, capsys):
    """``--objects 7 8`` resets Grasp with the unseen block types only; each episode records its block and the
    summary counts them per type. Names outside the family, a task without objects and hand-offs are refused."""
    out = tmp_path / "unseen.json"
    assert main(["rollout", "--task", "grasp", "--zero-action", "--test", "--episodes", "4", "--objects", "7", "8",
                 "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["object_types"] == [7, 8]
    kinds = [record["object"].split("_")[1] for record in result["per_episode"]]
    assert set(kinds) <= {"7", "8"} and len(kinds) == 4
    per_object = result["per_object"]
    assert sum(counts["episodes"] for counts in per_object.values()) == 4
    assert {f"block {kind}" for kind in kinds} == set(per_object)
    assert sum(counts["successes"] for counts in per_object.values()) == sum(
        record["success"] for record in result["per_episode"])
    # scripts/rollout_table.py tabulates it by type; a file without recorded objects is refused.
    table = subprocess.run([sys.executable, str(ROOT / "scripts" / "rollout_table.py"), str(out)],
                           capture_output=True, text=True, check=True).stdout
    for kind, counts in per_object.items():
        assert f"| grasp | {kind} | {counts['successes']}/{counts['episodes']} |" in table
    old = tmp_path / "old.json"
    old.write_text(json.dumps({key: value for key, value in result.items() if key != "per_object"}))
    refused = subprocess.run([sys.executable, str(ROOT / "scripts" / "rollout_table.py"), str(old)],
                             capture_output=True, text=True)
    assert refused.returncode == 2 and "do not record their object" in refused.stderr
    capsys.readouterr()
    for bad, message in ((["--task", "grasp", "--objects", "9"], "unknown block type '9'"),
                         (["--task", "tool_grasp", "--objects", "3"], "unknown tool '3'"),
                         (["--task", "reach", "--objects", "1"], "nothing to choose")):
        assert main(["rollout", "--zero-action", "--test", *bad]) == 2
        assert message in capsys.readouterr().err
    # Insert's reset cannot pick up the 2x2 type 8: a clear error before anything is written.
    wide = tmp_path / "wide.json"
    assert main(["rollout", "--task", "insert", "--zero-action", "--test", "--objects", "8", "--out",
                 str(wide)]) == 2
    err = capsys.readouterr().err
    assert "block type 8 is 6 cm wide" in err and "Grasp's hand-offs" in err and "Traceback" not in err
    assert not wide.exists()
    buffer = str(tmp_path / "tool.npz")
    _tool_grasp_buffer(buffer)
    assert main(["rollout", "--task", "tool_reorient", "--zero-action", "--test", "--initial-states", buffer,
                 "--objects", "hammer"]) == 2
    assert "each hand-off fixes it" in capsys.readouterr().err


def test_collect_of_chosen_objects_hands_over_only_those(tmp_path, capsys):
    """``seqdex collect --objects 8`` rolls Grasp out on the unseen 2x2 only (Insert's own reset cannot pick it up,
    so its episodes start from Grasp's hand-offs); unknown names are refused before any rollout."""
    from seqdex_drake.chaining.terminal_buffer import TerminalBuffer

    shipped = ROOT / "checkpoints" / "building_blocks" / "stages" / "grasp" / "best.pt"
    out = tmp_path / "wide.npz"
    assert main(["collect", "--task", "grasp", "--checkpoint", str(shipped), "--preset", "budget", "--test",
                 "--episodes", "2", "--keep-failures", "--objects", "8", "--out", str(out)]) == 0
    buffer = TerminalBuffer.load(out, expected_task="insert")
    assert len(buffer) == 2 and all(buffer.state(i)["target_object"] == "block_8" for i in range(2))
    capsys.readouterr()
    assert main(["collect", "--task", "grasp", "--checkpoint", str(shipped), "--preset", "budget", "--test",
                 "--objects", "9", "--out", str(tmp_path / "none.npz")]) == 2
    assert "unknown block type '9'" in capsys.readouterr().err and not (tmp_path / "none.npz").exists()


def test_rollout_on_another_scene_from_a_hand_off_buffer(tmp_path, capsys):
    """``--scene`` runs a sub-task on another station scenario (block Orient in the whole pile): the hand-offs
    restore that scene's state; without hand-offs, or with an unknown scenario, it is refused before any rollout."""
    buffer, out = str(tmp_path / "tool.npz"), tmp_path / "rollout.json"
    _tool_grasp_buffer(buffer)
    assert main(["rollout", "--task", "tool_reorient", "--zero-action", "--test", "--episodes", "1",
                 "--initial-states", buffer, "--scene", "tool_positioning/tool_grasp", "--out", str(out)]) == 0
    assert json.loads(out.read_text())["scene"] == "tool_positioning/tool_grasp"
    capsys.readouterr()
    assert main(["rollout", "--task", "orient", "--zero-action", "--test", "--scene", "building_blocks/search"]) == 2
    assert "needs --initial-states" in capsys.readouterr().err
    assert main(["rollout", "--task", "tool_reorient", "--zero-action", "--test", "--initial-states", buffer,
                 "--scene", "building_blocks/pile"]) == 2
    assert "unknown scenario 'building_blocks/pile'" in capsys.readouterr().err
