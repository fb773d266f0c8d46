"""Orient (Building Blocks): rotate the target block, freely, until it stands upright.

Reset: one block of a training type lies in the box upside down or on a long side (upright would already
be done), random yaw, the open hand 5 cm above it. Reward: lambda1 * (rotation since the start) + the
fingertip term and penalties (paper). Success (release): the block's z axis within acos(0.6) of world z.

:func:`budget_config` is the variant that fits a small training budget (``../shared/TRAINING.md``), as block
Grasp's: a residual policy (``tasks/residual.py``) on the scripted fingertip roll of
``tasks/scripted/block_orient_script.py`` (the script alone: see its docstring), the episode's progress in the
observation (160 entries), no hand smoothing; the policy learns a wrist correction (3 dims; the hand's 16 are
pinned to the script's).
"""

import dataclasses

from seqdex_drake.observation_layout import OBJECT_QUATERNION
from seqdex_drake.tasks.base import Task, TaskConfig
from seqdex_drake.tasks.blocks_common import place_single_block
from seqdex_drake.tasks.rewards import RewardWeights, orient_reward, quaternion_angle


def default_config() -> TaskConfig:
    return TaskConfig(
        name="orient", scenario="building_blocks/orient", episode_length=75, ema=0.2,
        reward=RewardWeights(progress=1.0, fingertip=1.0, action=-0.001, torque=-0.003, e0=0.6),
        success_threshold=[0.6])  # [minimum dot product of the block's z axis with world z]


def budget_config() -> TaskConfig:
    """The small-budget variant: the policy a residual on the scripted fingertip roll that corrects its wrist (the
    script's hand applies as it is), with the episode's progress observed. Changed from the default, and why:
    ``ema`` 1.0, as the script's hand is a timed schedule (open, then the stylus shape over steps 5-12) and the
    release's 0.2 smoothing would lag it by about 10 steps while the wrist already lowers the tip, and the hand
    is not the policy's to move (no jitter to smooth); ``observe_time``, as the base reads the step (the shape's
    schedule), so the policy's state should too; ``hand_actions`` False, as block Grasp's: the policy corrects
    the wrist only (hand corrections at the initial exploration noise would move the stylus tip by about 1 cm,
    more than the stroke's 4 mm press). ``episode_length`` stays 75: the script stands a side-lying
    block up by about step 30 and an upside-down one by steps 50-65 (0.88 success alone over 300 episodes)."""
    config = default_config()
    return dataclasses.replace(config, ema=1.0, observe_time=True, residual="block_orient_script",
                               hand_actions=False)


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
