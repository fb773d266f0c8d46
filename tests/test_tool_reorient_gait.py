"""Tool Reorient's scripted base: the searched finger gait (``tasks/scripted/tool_reorient_gait.py``), its search script
(``experiments/search_reorient_gait.py``) and the task's held-tool rule (``tasks/tool_reorient.py``)."""

import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pydrake.math import RigidTransform

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.tasks.registry import default_config
from seqdex_drake.tasks.residual import make_base
from seqdex_drake.tasks.scripted.tool_reorient_gait import GAIT_FILE, FingerGait, GaitParameters, load_gait

ROOT = Path(__file__).resolve().parents[1]


def _gait(period=20.0) -> GaitParameters:
    rng = np.random.default_rng(0)
    return GaitParameters(tuple(rng.uniform(-0.5, 0.5, 16)), tuple(rng.uniform(0, 0.5, 16)),
                          tuple(rng.uniform(-3, 3, 16)), period)


def test_gait_parameters_round_trip_and_are_clipped_from_a_search_vector():
    gait = _gait()
    np.testing.assert_allclose(GaitParameters.from_vector(gait.to_vector()).to_vector(), gait.to_vector(), atol=1e-12)
    assert GaitParameters.from_dict(json.loads(json.dumps(gait.to_dict()))) == gait
    wild = np.r_[np.full(16, 3.0), np.full(16, -0.2), np.full(16, 7.0), 500.0]
    clipped = GaitParameters.from_vector(wild)
    assert max(clipped.center) == 1.0 and min(clipped.amplitude) == pytest.approx(0.2)
    assert all(-math.pi <= p < math.pi for p in clipped.phase) and clipped.period == 120.0
    with pytest.raises(ValueError, match="49 numbers"):
        GaitParameters.from_vector(np.zeros(48))
    with pytest.raises(ValueError, match="center"):
        dataclasses.replace(gait, center=(0.0,) * 15)
    with pytest.raises(ValueError, match="period"):
        dataclasses.replace(gait, period=5.0)


def test_the_gait_moves_the_hand_periodically_and_holds_the_wrist():
    gait = FingerGait(_gait(period=20.0))
    actions = np.array([gait.act(None, step) for step in range(41)])
    assert actions.shape == (41, 19) and np.all(np.abs(actions) <= 1.0)
    assert np.all(actions[:, 16:] == 0.0)
    np.testing.assert_allclose(actions[0], actions[20], atol=1e-12)
    np.testing.assert_allclose(actions[3], actions[23], atol=1e-12)
    assert not np.allclose(actions[0], actions[5])


def test_the_gait_holds_the_previous_hand_action_once_the_tool_is_near_its_goal():
    from seqdex_drake.observation_layout import GOAL_ROTATION_ERROR, PREVIOUS_ACTION
    from seqdex_drake.tasks.scripted.tool_reorient_gait import HOLD_BELOW

    gait = FingerGait(_gait())
    observation = np.zeros(174)
    observation[PREVIOUS_ACTION] = np.linspace(-0.9, 0.9, 19)
    far, near = HOLD_BELOW + 0.1, HOLD_BELOW - 0.1
    observation[GOAL_ROTATION_ERROR] = [math.cos(far / 2), 0.0, math.sin(far / 2), 0.0]
    np.testing.assert_allclose(gait.act(observation, 7), gait.act(None, 7))  # Far: the gait.
    observation[GOAL_ROTATION_ERROR] = [math.cos(near / 2), 0.0, math.sin(near / 2), 0.0]
    held = gait.act(observation, 7)  # Near: the previous hand action, the wrist still.
    np.testing.assert_allclose(held[:16], observation[PREVIOUS_ACTION][:16])
    assert np.all(held[16:] == 0.0)


def test_load_gait_names_a_missing_or_foreign_file(tmp_path):
    with pytest.raises(ValueError, match="search_reorient_gait.py"):
        load_gait(tmp_path / "none.json")
    (tmp_path / "bad.json").write_text('{"gait": {"center": [1]}}')
    with pytest.raises(ValueError, match="not a reorient gait file"):
        load_gait(tmp_path / "bad.json")
    (tmp_path / "binary.json").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ValueError, match="not a reorient gait file"):
        load_gait(tmp_path / "binary.json")


def test_the_shipped_gait_is_a_residual_base_the_env_applies():
    assert GAIT_FILE.is_file()
    base = make_base("tool_reorient_gait")
    config = dataclasses.replace(default_config("tool_reorient"), residual="tool_reorient_gait")
    env = make_env("tool_reorient", config)
    try:
        env.reset(seed=0)
        env.step(np.zeros(19))
        # The zero correction applies the gait's step-0 hand targets.
        from seqdex_drake.robots.allegro import unscale_limits_to_action

        np.testing.assert_allclose(unscale_limits_to_action(env._hand_target), base.act(None, 0)[:16], atol=1e-9)
    finally:
        env.close()


def test_a_tool_that_leaves_the_hand_ends_the_episode_as_a_failure():
    env = make_env("tool_reorient")
    try:
        env.reset(seed=1)
        from seqdex_drake.tasks.handoff import hold_action

        for _ in range(3):  # Held: in place, not flipped.
            _, _, terminated, _, info = env.step(hold_action(env))
            assert not terminated and not info["success"]
        X_WT = env.object_pose()  # Carried away 0.2 m (as if thrown): failure, whatever its orientation.
        env.objects.set_pose(env.context, env.target_object,
                             RigidTransform(X_WT.rotation(), X_WT.translation() + [0.0, 0.0, -0.2]), frozen=False)
        _, _, terminated, _, info = env.step(hold_action(env))
        assert terminated and not info["success"]
    finally:
        env.close()


def test_search_script_scores_candidates_and_writes_the_best(tmp_path):
    out = tmp_path / "gait.json"
    command = [sys.executable, str(ROOT / "experiments" / "search_reorient_gait.py"), "--iterations", "1",
               "--population", "2", "--elites", "1", "--starts", "1", "--workers", "1", "--out", str(out)]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    record = json.loads(out.read_text())
    gait = load_gait(out)
    assert -(math.pi + 1.0) <= record["score"] <= 0.0 and record["successes"] in (0, 1)
    assert record["env_steps"] == 2 * default_config("tool_reorient").episode_length
    assert record["search"]["iterations"] == 1 and len(record["search"]["mean"]) == GaitParameters.SIZE
    assert len(record["runs"]) == 1 and record["runs"][0]["iterations"] == [1, 1]
    assert gait.period >= 10.0
    # Resuming continues the count; bad input is refused with a message.
    done = subprocess.run([*command, "--resume"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    resumed = json.loads(out.read_text())
    assert done.returncode == 0 and resumed["search"]["iterations"] == 2
    assert [run["iterations"] for run in resumed["runs"]] == [[1, 1], [2, 2]]
    assert "--resume" in resumed["runs"][1]["command"]
    done = subprocess.run([*command[:2], "--buffer", str(tmp_path / "none.npz"), "--out", str(out)], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "seqdex collect --task tool_grasp" in done.stderr and "Traceback" not in done.stderr
