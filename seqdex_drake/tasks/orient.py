"""Orient (Building Blocks): rotate the target block, freely, until it stands upright.

Reset: one block of a training type lies in the box upside down or on a long side (upright would already
be done), random yaw, the open hand 5 cm above it. Reward: lambda1 * (rotation since the start) + the
fingertip term and penalties (paper). Success (release): the block's z axis within acos(0.6) of world z.
"""

from seqdex_drake.observation_layout import OBJECT_QUATERNION
from seqdex_drake.tasks.base import Task, TaskConfig
from seqdex_drake.tasks.blocks_common import place_single_block
from seqdex_drake.tasks.rewards import RewardWeights, orient_reward, quaternion_angle


def default_config() -> TaskConfig:
    return TaskConfig(
        name="orient", scenario="building_blocks/orient", episode_length=75, ema=0.2,
        reward=RewardWeights(progress=1.0, fingertip=1.0, action=-0.001, torque=-0.003, e0=0.6),
        success_threshold=[0.6])  # [minimum dot product of the block's z axis with world z]


class OrientTask(Task):
    """Turn a block upright."""

    def reset(self, env, rng) -> None:
        place_single_block(env, rng, ["upside_down", "side_left", "side_right"])
        self.on_restore(env)

    def on_restore(self, env, from_task: str = "") -> None:
        self.start_quaternion = env.object_pose().rotation().ToQuaternion().wxyz()

    def reward_terms(self, env, action):
        rotation = quaternion_angle(env.observation_values()[OBJECT_QUATERNION], self.start_quaternion)
        return orient_reward(self.config.reward, rotation, env.fingertip_distance(), action, env.hand_torque())

    def is_success(self, env) -> bool:
        _, x, y, _ = env.observation_values()[OBJECT_QUATERNION]
        return 1.0 - 2.0 * (x * x + y * y) > self.config.success_threshold[0]  # The body z axis's world z.
