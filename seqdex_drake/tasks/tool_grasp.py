"""Tool Grasp (Tool Positioning): pick the tool up from the table.

Reset: the hammer (training; spatula and spoon unseen, ``object_types`` 1 and 2) lies on the table at
(0.29, 0.19) with a random yaw within +-45 deg, settled; the open hand hovers 5 cm above its top over its
centre of mass. Reward: the paper's Grasp formula. Success: lifted at least 0.10 m above its start with its
orientation within 0.3 rad of the start (FACTS.md's 0.3 rad orientation error: a grasp, not a flip).
"""

from seqdex_drake.systems.observations import OBJECT_QUATERNION
from seqdex_drake.tasks.base import Task, TaskConfig
from seqdex_drake.tasks.rewards import RewardWeights, grasp_reward, quaternion_angle
from seqdex_drake.tasks.tools_common import place_tool_on_table


def default_config() -> TaskConfig:
    return TaskConfig(
        name="tool_grasp", scenario="tool_positioning/tool_grasp", episode_length=150, ema=1.0,
        object_types=[0], reward=RewardWeights(progress=1.0, action=-0.001, torque=-0.003, alpha0=-5.0, e0=0.1),
        success_threshold=[0.10, 0.3])  # [lift (m), orientation change (rad)]


class ToolGraspTask(Task):
    """Lift a tool off the table."""

    def reset(self, env, rng) -> None:
        place_tool_on_table(env, rng)
        self.on_restore(env)

    def on_restore(self, env, from_task: str = "") -> None:
        self.start_height = float(env.object_position()[2])
        self.start_quaternion = env.object_pose().rotation().ToQuaternion().wxyz()

    def reward_terms(self, env, action):
        return grasp_reward(self.config.reward, env.fingertip_distance(), action, env.hand_torque())

    def is_success(self, env) -> bool:
        lift, angle = self.config.success_threshold
        turned = quaternion_angle(env.observation_values()[OBJECT_QUATERNION], self.start_quaternion)
        return env.object_position()[2] - self.start_height > lift and turned < angle
