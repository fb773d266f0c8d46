"""The thin, light tools (spatula, ladle) stay physical under any grasp (issue 39: the spoon's simulation once
diverged in 19 of 102 chain episodes, the spatula's in 7).

Each tool lies on the table as tool Grasp's reset lays it (random yaw) and the hand acts on it for a whole episode
(150 steps): hand and wrist actions drawn uniformly from the whole action space (the default config: absolute hand
targets), which slam the fingers into the handle at any step, and the two scripted grasps with their lift (the fist
the chain runs, the yaw-planned pinch). Every step must give a finite observation and reward and no simulator error,
and the tool's speed must stay within what a tool batted by a hand can reach (a blown-up state runs to 1e160 m/s);
it must never sink through the table. About 10 s.
"""

import dataclasses

import numpy as np
import pytest

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.tasks.registry import budget_config, default_config
from seqdex_drake.tasks.tools_common import TABLE_TOP

TOOLS = {"spatula": 1, "spoon": 2}
#: Bounds a physical episode stays within: the fastest batted ladle measured 4 m/s and 40 rad/s.
MAX_LINEAR_SPEED = 10.0
MAX_ANGULAR_SPEED = 200.0
#: How far (m) the tool's origin may dip below the table top (its frame sits inside the handle, above the table).
TABLE_MARGIN = 0.02


def _run_episode(env, seed: int, policy) -> dict:
    env.reset(seed=seed)
    body = env.objects.bodies[env.objects.index(env.target_object)]
    worst = {"linear": 0.0, "angular": 0.0, "lowest": np.inf}
    for step in range(150):
        observation, reward, terminated, truncated, info = env.step(policy(step))
        assert np.all(np.isfinite(observation)) and np.isfinite(reward), f"non-finite at step {step}"
        assert not info["simulator_error"], info["simulator_error"]
        V_WT = env.plant.EvalBodySpatialVelocityInWorld(env.plant_context, body)
        worst["linear"] = max(worst["linear"], float(np.linalg.norm(V_WT.translational())))
        worst["angular"] = max(worst["angular"], float(np.linalg.norm(V_WT.rotational())))
        worst["lowest"] = min(worst["lowest"], float(env.object_position()[2]))
        if terminated or truncated:
            break
    return worst


def _assert_physical(worst: dict, what: str) -> None:
    assert worst["linear"] < MAX_LINEAR_SPEED, f"{what}: the tool reached {worst['linear']:.3g} m/s"
    assert worst["angular"] < MAX_ANGULAR_SPEED, f"{what}: the tool reached {worst['angular']:.3g} rad/s"
    assert worst["lowest"] > TABLE_TOP - TABLE_MARGIN, f"{what}: the tool sank to z = {worst['lowest']:.3f} m"


@pytest.mark.parametrize("tool", list(TOOLS))
def test_random_actions_keep_the_thin_tools_physical(tool):
    env = make_env("tool_grasp", dataclasses.replace(default_config("tool_grasp"), object_types=[TOOLS[tool]]))
    assert env.config.hand_actions and env.action_space.shape == (19,)
    for seed in range(2):
        rng = np.random.default_rng([seed, TOOLS[tool]])
        worst = _run_episode(env, seed, lambda step, rng=rng: rng.uniform(-1.0, 1.0, env.action_space.shape))
        assert env.target_object == tool
        _assert_physical(worst, f"{tool}, random actions, seed {seed}")


@pytest.mark.parametrize("tool", list(TOOLS))
@pytest.mark.parametrize("base", ["tool_grasp_script", "tool_pinch_script"])
def test_the_scripted_grasps_keep_the_thin_tools_physical(tool, base):
    config = dataclasses.replace(budget_config("tool_grasp"), object_types=[TOOLS[tool]], residual=base)
    env = make_env("tool_grasp", config)
    zero = np.zeros(env.action_space.shape)
    _assert_physical(_run_episode(env, 0, lambda step: zero), f"{tool}, {base}, seed 0")
