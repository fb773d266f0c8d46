"""Tool Grasp (Tool Positioning): pick the tool up from the table.

Reset: the hammer (training; spatula and spoon unseen, ``object_types`` 1 and 2) lies on the table at
(0.29, 0.19) with a random yaw within +-45 deg, settled; the open hand hovers 5 cm above its top over its
centre of mass. Reward: the paper's Grasp formula. Success: lifted at least 0.10 m above its start with its
orientation within 0.3 rad of the start (FACTS.md's 0.3 rad orientation error: a grasp, not a flip).

:func:`budget_config` is the variant that fits a small training budget (``../shared/TRAINING.md``): the
release's scripted phases (the policy's wrist for 60 steps, a scripted lift over steps 60-90, then the hand
frozen), the episode's progress in the observation (160 entries: the phases are timed) and a lift term in the
reward, so that what the policy must learn is the approach and the closing; and a residual policy
(``tasks/residual.py``) on the scripted pickup of ``tasks/scripted/tool_grasp_script.py`` (40 % success alone): the
policy
learns a wrist correction (3 dims; the hand's 16 are pinned to the script's) that makes the script's grasp hold,
starting from the script's success rather than from none.
"""

import dataclasses

from seqdex_drake.observation_layout import OBJECT_QUATERNION
from seqdex_drake.tasks.base import Task, TaskConfig
from seqdex_drake.tasks.phases import release_tool_grasp_phases
from seqdex_drake.tasks.rewards import RewardWeights, grasp_reward, quaternion_angle
from seqdex_drake.tasks.tools_common import place_tool_on_table


def default_config() -> TaskConfig:
    return TaskConfig(
        name="tool_grasp", scenario="tool_positioning/tool_grasp", episode_length=150, ema=1.0,
        object_types=[0], reward=RewardWeights(progress=1.0, action=-0.001, torque=-0.003, alpha0=-5.0, e0=0.1),
        success_threshold=[0.10, 0.3])  # [lift (m), orientation change (rad)]


def budget_config() -> TaskConfig:
    """The small-budget variant: the release's scripted phases, the episode's progress in the observation (when
    the lift comes), a lift term (weight 2) in the reward, and the policy a residual on the scripted pickup that
    corrects its wrist (the script's fingers apply as they are: noise on them breaks the fist grasp)."""
    config = default_config()
    return dataclasses.replace(config, phases=release_tool_grasp_phases(), observe_time=True,
                               reward=dataclasses.replace(config.reward, lift=2.0), residual="tool_grasp_script",
                               hand_actions=False)


class ToolGraspTask(Task):
    """Lift a tool off the table."""

    def reset(self, env, rng) -> None:
        place_tool_on_table(env, rng)
        self.on_restore(env)

    def on_restore(self, env, from_task: str = "") -> None:
        self.start_height = float(env.object_position()[2])
        self.start_quaternion = env.object_pose().rotation().ToQuaternion().wxyz()

    def reward_terms(self, env, action):
        terms = grasp_reward(self.config.reward, env.fingertip_distance(), action, env.hand_torque())
        if self.config.reward.lift:
            rise, turned = self._lift_and_turn(env)
            lift, angle = self.config.success_threshold
            terms["lift"] = self.config.reward.lift * (min(max(rise / lift, 0.0), 1.0) if turned < angle else 0.0)
        return terms

    def _lift_and_turn(self, env) -> tuple[float, float]:
        """The object's rise above its start (m) and its rotation from the start orientation (rad)."""
        turned = quaternion_angle(env.observation_values()[OBJECT_QUATERNION], self.start_quaternion)
        return float(env.object_position()[2]) - self.start_height, turned

    def is_success(self, env) -> bool:
        lift, angle = self.config.success_threshold
        rise, turned = self._lift_and_turn(env)
        return rise > lift and turned < angle
