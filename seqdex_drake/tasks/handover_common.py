"""The hand-over chain (Reach, then Lower): a cheap two-stage chain on the full station, for method comparisons.

Both stages run in the ``handover/*`` scene (the Franka + Allegro, the table, one block) and share one plant, so
Reach's terminal states restore exactly into Lower. The chain is built so that Reach's own reward ignores a
state dimension that decides Lower's success: Reach is rewarded for bringing the hand centre over the block in
x-y only (its optional clearance term has weight 0 by default); Lower must then bring it down to 4 cm above the
block within 15 steps, which only works when Reach left the hand low enough (about 12.5 cm above the block or
lower).
Forward initialization alone (Policy-Seq) inherits Reach's arbitrary heights; backward fine-tuning with the
feasibility function should teach Reach to end low.

The hand centre (``p_PalmHc_Palm``) is the point the wrist action moves; heights are above the block's position
(``env.object_position()``, 2.9 cm above the table for block type 1). Only the wrist acts
(``hand_actions=False``: the hand stays open).
"""

import numpy as np

from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q
from seqdex_drake.tasks.blocks_common import block_name, resting_pose

#: Block positions are sampled in this x-y rectangle on the table (centre, half sizes), within easy reach.
TABLE_XY_CENTER = np.array([0.37, 0.08])
TABLE_XY_HALF = np.array([0.04, 0.04])
#: The table top's height in the ``handover`` scene (models/fixtures_table.dmd.yaml).
TABLE_TOP = 0.6
#: The wrist command keeps the hand centre at least this high (7 cm above the table, where the block's frame
#: sits): lower, the fingers would catch on the table and the block, and friction would pin the hand.
WRIST_FLOOR = TABLE_TOP + 0.07


def hand_center(env) -> np.ndarray:
    """World position of the hand centre (the point the wrist action translates), from the measured arm."""
    return env.ik.palm_position(env.arm_q())


def place_block_and_hand(env, rng: np.random.Generator, offset_low: np.ndarray, offset_high: np.ndarray) -> None:
    """Puts an upright block of a sampled type on the table at a random yaw and the open hand's centre at a
    uniformly sampled offset in [offset_low, offset_high] (m, world frame) from the block's centre."""
    block_type = int(rng.choice(env.config.object_types))
    name = block_name(block_type)
    env.objects.park(env.context)
    xy = TABLE_XY_CENTER + rng.uniform(-TABLE_XY_HALF, TABLE_XY_HALF)
    env.objects.set_pose(env.context, name, resting_pose(block_type, 0.0, 0.0, rng.uniform(-np.pi, np.pi), xy,
                                                         floor=TABLE_TOP), frozen=False)
    env.set_target(name)
    p_WC = env.object_position() + rng.uniform(offset_low, offset_high)
    q, error = env.ik.solve(np.asarray(env.scenario.robot.arm_home), p_WC, env.R_WP_hold)
    if error > 0.01:
        raise RuntimeError(f"the hand start {np.round(p_WC, 3)} is out of reach ({error:.3f} m)")
    env.set_robot(q, ALLEGRO_OPEN_Q)
