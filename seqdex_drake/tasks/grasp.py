"""Grasp (Building Blocks): lift the target block and hold it in hand.

Reset: one block of a training type stands upright (Orient's success) at a random yaw in the box, the open
hand hovers 5 cm above it. Success: lifted more than 0.30 m (paper) with the four fingertips within 0.4 m of
it in total (release). Reward: the paper's Grasp formula (see ``tasks/rewards.py`` for its sign note).

:func:`budget_config` is the variant that fits a small training budget (``../shared/TRAINING.md``), as tool
Grasp's: the release's scripted phases (the policy's wrist for 75 steps, then a scripted lift to the end), the
episode's progress in the observation (160 entries: the phases are timed), a lift term in the reward, and a
residual policy (``tasks/residual.py``) on the scripted pickup of ``tasks/scripted/block_grasp_script.py`` (30 / 30
alone on seeds 0-29): the policy learns a wrist correction (3 dims; the
hand's 16 are pinned to the script's).
"""

import dataclasses

from seqdex_drake.tasks.base import Task, TaskConfig
from seqdex_drake.tasks.blocks_common import place_single_block
from seqdex_drake.tasks.phases import release_block_grasp_phases
from seqdex_drake.tasks.rewards import RewardWeights, grasp_reward


def default_config() -> TaskConfig:
    return TaskConfig(
        name="grasp", scenario="building_blocks/grasp", episode_length=150, ema=1.0,
        reward=RewardWeights(progress=1.0, action=-0.001, torque=-0.003, alpha0=-5.0, e0=0.1),
        success_threshold=[0.30, 0.4])  # [lift height (m), fingertip distance sum (m)]


def budget_config() -> TaskConfig:
    """The small-budget variant: the release's scripted phases, the episode's progress in the observation (when
    the lift comes), a lift term (weight 2) in the reward, and the policy a residual on the scripted pickup that
    corrects its wrist (the script's fingers apply as they are)."""
    config = default_config()
    return dataclasses.replace(config, phases=release_block_grasp_phases(), observe_time=True,
                               reward=dataclasses.replace(config.reward, lift=2.0), residual="block_grasp_script",
                               hand_actions=False)


class GraspTask(Task):
    """Lift a block out of the box."""

    def reset(self, env, rng) -> None:
        place_single_block(env, rng, ["upright"])
        self.on_restore(env)

    def on_restore(self, env, from_task: str = "") -> None:
        self.start_height = float(env.object_position()[2])

    def reward_terms(self, env, action):
        terms = grasp_reward(self.config.reward, env.fingertip_distance(), action, env.hand_torque())
        if self.config.reward.lift:  # The block's rise as a fraction of the success lift, while it is in hand.
            lift, reach = self.config.success_threshold
            rise = float(env.object_position()[2]) - self.start_height
            terms["lift"] = self.config.reward.lift * (min(max(rise / lift, 0.0), 1.0)
                                                       if env.fingertip_distance() < reach else 0.0)
        return terms

    def is_success(self, env) -> bool:
        lift, reach = self.config.success_threshold
        return env.object_position()[2] - self.start_height > lift and env.fingertip_distance() < reach
