"""Reach (hand-over chain, stage 1): bring the hand centre over the block, in x-y only.

Reset: an upright block on the table, the open hand's centre 0-4 cm away in x and y and 12-26 cm above the
block. Reward: lambda1 exp(-alpha0 d_xy), d_xy the horizontal distance from the hand centre to the block, plus an
optional clearance term, w_c clip((h - 0.10) / 0.16, 0, 1) with h the hand centre's height above the block (w_c =
``CLEARANCE_WEIGHT``, 0 by default: the height is then ignored; see ``handover_common``). The action and torque
penalties have zero weight: only the wrist acts.
Success (at the episode's end, which is the hand-over): d_xy < 0.02 m.
"""

import numpy as np

from seqdex_drake.tasks.base import Task, TaskConfig
from seqdex_drake.tasks.handover_common import WRIST_FLOOR, hand_center, place_block_and_hand
from seqdex_drake.tasks.rewards import RewardWeights, penalties


def default_config() -> TaskConfig:
    return TaskConfig(
        name="reach", scenario="handover/reach", episode_length=30, ema=1.0,
        hand_actions=False, wrist_floor=WRIST_FLOOR,
        reward=RewardWeights(progress=1.0, action=0.0, torque=0.0, alpha0=20.0, clearance=CLEARANCE_WEIGHT),
        # success_threshold: [horizontal distance of the hand centre to the block (m)]
        object_types=[1], success_threshold=[0.02],
        drop_height=0.3)


#: Weight of the clearance term per step. 0 by default: Reach's reward then ignores the height, so its hand-over
#: heights vary and F sees both usable and unusable ones (the design the method comparison needs). 0.03 (at most
#: 0.9 per episode against up to 30 for x-y closeness) makes Reach prefer high hand-overs that Lower cannot use,
#: and F then never sees a usable one.
CLEARANCE_WEIGHT = 0.0
#: Heights (m, above the block) where the clearance term starts (Lower's goal) and saturates.
CLEARANCE_LOW, CLEARANCE_HIGH = 0.10, 0.26

#: Start offsets of the hand centre from the block (m): [low, high] per axis.
START_LOW, START_HIGH = np.array([-0.04, -0.04, 0.12]), np.array([0.04, 0.04, 0.26])


class ReachTask(Task):
    """Hover over the block (any height)."""

    def reset(self, env, rng) -> None:
        place_block_and_hand(env, rng, START_LOW, START_HIGH)

    def xy_distance(self, env) -> float:
        return float(np.linalg.norm((hand_center(env) - env.object_position())[:2]))

    def reward_terms(self, env, action):
        w = self.config.reward
        height = float(hand_center(env)[2] - env.object_position()[2])
        clearance = np.clip((height - CLEARANCE_LOW) / (CLEARANCE_HIGH - CLEARANCE_LOW), 0.0, 1.0)
        return {"xy_closeness": w.progress * float(np.exp(-w.alpha0 * self.xy_distance(env))),
                "clearance": w.clearance * float(clearance), **penalties(w, action, env.hand_torque())}

    def is_success(self, env) -> bool:
        return self.xy_distance(env) < self.config.success_threshold[0]
