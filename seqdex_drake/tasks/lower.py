"""Lower (hand-over chain, stage 2): bring the hand centre down to just above the block in a few steps.

Reset (standalone): the hand centre within 1.5 cm (per axis) of the block's vertical line (Reach's success) at a
height of 5-20 cm above the block. From a hand-over, Reach's terminal state. The goal point is 4 cm above the
block's centre (its frame, on the table): the lowest the wrist command goes (``WRIST_FLOOR``), so going straight
down at full speed is the best Lower can do from any start, and whether it arrives depends only on where Reach
left the hand. The episode is 15 steps of at most 5 mm: a scripted straight-down policy succeeds from 12.5 cm
above the block, not from 13 cm (``LOWER_REACH`` in ``benchmarks/chain_methods.py``). Reward: lambda1
exp(-alpha0 d), d the distance from the hand centre to the goal point (the action and torque penalties have zero
weight: only the wrist acts). Success (at the episode's end): d < 0.02 m.

Until session 4 the goal was 10 cm above the block with 10 steps: Reach's hand-overs then needed the hand moved
up from some (the wrist floor) and down from others, a bimodal policy that PPO did not learn at this budget (0-2 %
training success from forward initialization, where a scripted controller reached 83 %).
"""

import numpy as np

from seqdex_drake.tasks.base import Task, TaskConfig
from seqdex_drake.tasks.handover_common import WRIST_FLOOR, hand_center, place_block_and_hand
from seqdex_drake.tasks.rewards import RewardWeights, penalties


def default_config() -> TaskConfig:
    return TaskConfig(
        name="lower", scenario="handover/lower", episode_length=15, ema=1.0,
        hand_actions=False, wrist_floor=WRIST_FLOOR,
        reward=RewardWeights(progress=1.0, action=0.0, torque=0.0, alpha0=20.0),
        # success_threshold: [distance to the goal point (m), goal height above the block (m)]
        object_types=[1], success_threshold=[0.02, 0.04],
        drop_height=0.3)


#: Standalone start offsets of the hand centre from the block (m): [low, high] per axis.
START_LOW, START_HIGH = np.array([-0.015, -0.015, 0.05]), np.array([0.015, 0.015, 0.20])


class LowerTask(Task):
    """Lower the hand to just above the block."""

    def reset(self, env, rng) -> None:
        place_block_and_hand(env, rng, START_LOW, START_HIGH)

    def distance(self, env) -> float:
        goal = env.object_position() + [0.0, 0.0, self.config.success_threshold[1]]
        return float(np.linalg.norm(hand_center(env) - goal))

    def reward_terms(self, env, action):
        w = self.config.reward
        return {"closeness": w.progress * float(np.exp(-w.alpha0 * self.distance(env))),
                **penalties(w, action, env.hand_torque())}

    def is_success(self, env) -> bool:
        return self.distance(env) < self.config.success_threshold[0]
