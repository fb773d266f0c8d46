"""Grasp (Building Blocks): lift the target block and hold it in hand.

Reset: one block of a training type stands upright (Orient's success) at a random yaw in the box, the open
hand hovers 5 cm above it. Success: lifted more than 0.30 m (paper) with the four fingertips within 0.4 m of
it in total (release). Reward: the paper's Grasp formula (see ``tasks/rewards.py`` for its sign note).
"""

from seqdex_drake.tasks.base import Task, TaskConfig
from seqdex_drake.tasks.blocks_common import place_single_block
from seqdex_drake.tasks.rewards import RewardWeights, grasp_reward


def default_config() -> TaskConfig:
    return TaskConfig(
        name="grasp", scenario="building_blocks/grasp", episode_length=150, ema=1.0,
        reward=RewardWeights(progress=1.0, action=-0.001, torque=-0.003, alpha0=-5.0, e0=0.1),
        success_threshold=[0.30, 0.4])  # [lift height (m), fingertip distance sum (m)]


class GraspTask(Task):
    """Lift a block out of the box."""

    def reset(self, env, rng) -> None:
        place_single_block(env, rng, ["upright"])
        self.on_restore(env)

    def on_restore(self, env, from_task: str = "") -> None:
        self.start_height = float(env.object_position()[2])

    def reward_terms(self, env, action):
        return grasp_reward(self.config.reward, env.fingertip_distance(), action, env.hand_torque())

    def is_success(self, env) -> bool:
        lift, reach = self.config.success_threshold
        return env.object_position()[2] - self.start_height > lift and env.fingertip_distance() < reach
