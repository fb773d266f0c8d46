"""Insert (Building Blocks): put the block held in hand onto its goal on a 4x4 plate, studs seated.

Reset: a hand-off state from Grasp (``options={"initial_state": ...}``, forward initialization), the block in
hand then carried 3 cm over its goal and turned to its orientation as the whole chain's approach carries it
(``tasks/carry.py``), or standalone a scripted tripod pickup from the table (``tasks/handoff.py``). The goal: a
plate of 1-3 layers stands on the baseplate (frozen: a static support), the block's goal is stud-aligned on its
top at yaw 0 or 90 deg. Observation: base + goal pose, position and quaternion differences (173). Reward: the
paper's Insert formula. Success (release): within 0.02 m and 0.2 rad of the goal, a 180 deg yaw flip counting as
the goal. The goal yaws drawn are ``TaskConfig.goal_yaws_deg`` (default 0 and 90 deg).

:func:`budget_config` is the variant that fits a small training budget (``../shared/TRAINING.md``), as block
Grasp's: a residual policy (``tasks/residual.py``) on the scripted insertion of
``tasks/scripted/block_insert_script.py``
(alone 84, 80 and 83 / 100 at seeds 0, 1000 and 2000) that corrects its wrist (3 dims; the hand's 16 are pinned
to the script's), the episode's progress in the observation (174 entries: the script's release and lift are
timed), and yaw-90 goals only.
"""


import dataclasses

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw

from seqdex_drake.modeling.blocks import BLOCK_SPECS, STUD_PITCH
from seqdex_drake.observation_layout import OBJECT_QUATERNION, floats, pose_vector, quat_product
from seqdex_drake.tasks.base import ResetError, Task, TaskConfig
from seqdex_drake.tasks.blocks_common import block_name
from seqdex_drake.tasks.carry import carry_to_goal, restore_held_orientation
from seqdex_drake.tasks.handoff import scripted_block_pickup
from seqdex_drake.tasks.rewards import RewardWeights, goal_errors, goal_reward, quaternion_angle

#: The 4x4 plates stand stud-aligned on the baseplate (baseplate top at z = 0.618).
PLATE_XY = np.array([0.25, -0.23])
BASEPLATE_TOP = 0.618
LAYER_HEIGHT = 0.0375
PLATE_CELLS = 4
YAW_FLIP = (0.0, 0.0, 0.0, 1.0)  # Quaternion [w, x, y, z] of a 180 deg turn about z.


def default_config() -> TaskConfig:
    return TaskConfig(
        name="insert", scenario="building_blocks/insert", episode_length=125, ema=1.0,
        reward=RewardWeights(progress=1.0, fingertip=0.0, action=-0.001, torque=-0.003, alpha0=20.0,
                             alpha1=1.0, e0=0.06),
        success_threshold=[0.02, 0.2])  # [position (m), rotation (rad)] tolerances


def budget_config() -> TaskConfig:
    """The small-budget variant: a residual policy on the scripted insertion of
    ``tasks/scripted/block_insert_script.py``
    that corrects its wrist (the script's hand applies as it is: it holds the reset's grasp, then opens), the
    episode's progress in the observation (the script's release and lift are timed), and goals at yaw 90 deg
    only (the held block's long side lies along world y, and neither the wrist nor the script can turn it).
    The hand is not the policy's: the script holds the grasp by re-applying the previous applied hand action, so
    exploration noise on the hand would add up over the episode (a random walk of the grip) instead of averaging
    out."""
    return dataclasses.replace(default_config(), observe_time=True, residual="block_insert_script",
                               hand_actions=False, goal_yaws_deg=[90.0])


def goal_pose(block_type: int, layers: int, cell: tuple[int, int], yaw: float) -> np.ndarray:
    """Goal [x, y, z, qw, qx, qy, qz] of a block whose footprint starts at stud ``cell`` of the plate top."""
    nx, ny = BLOCK_SPECS[block_type].cells
    if yaw % np.pi:
        nx, ny = ny, nx
    offset = (np.array(cell) + np.array([nx, ny]) / 2 - PLATE_CELLS / 2) * STUD_PITCH
    X = RigidTransform(RollPitchYaw(0.0, 0.0, yaw), [*(PLATE_XY + offset), BASEPLATE_TOP + layers * LAYER_HEIGHT])
    return pose_vector(X)


def block_goal_errors(env) -> tuple[float, float]:
    """Position (m) and rotation (rad) errors of the block's origin frame to the goal, yaw-flip symmetric."""
    observation = env.observation_values()
    position, rotation = goal_errors(observation)
    flipped = quaternion_angle(observation[OBJECT_QUATERNION], quat_product(floats(env.goal[3:]), YAW_FLIP))
    return position, min(rotation, flipped)


#: Widest block [m] the reset's scripted tripod pickup holds (every type's 3 cm width but the 2x2 type 8's 6 cm).
PICKUP_MAX_WIDTH = 0.03


class InsertTask(Task):
    """Seat the held block on its goal."""

    goal = True

    def reset(self, env, rng) -> None:
        block_type = int(rng.choice(env.config.object_types))
        width = BLOCK_SPECS[block_type].footprint[1]
        if width > PICKUP_MAX_WIDTH:
            raise ResetError(f"Insert's reset picks the block up with a scripted tripod, which holds blocks up to "
                             f"{PICKUP_MAX_WIDTH * 100:.0f} cm wide; block type {block_type} is {width * 100:.0f} cm "
                             f"wide. Start its episodes from Grasp's hand-offs instead (seqdex rollout "
                             f"--initial-states, seqdex collect --task grasp)")
        name = block_name(block_type)
        env.objects.park(env.context)
        self.place_goal(env, rng, name)
        scripted_block_pickup(env, name, yaw_jitter=0.1, rng=rng)

    def on_restore(self, env, from_task: str = "") -> None:
        """A hand-off from another sub-task (forward initialization: Grasp's held block, carried over from its
        scene, ``envs/scene_handoff.py``) has no plate or goal: they are drawn as a reset draws them, from the
        env's generator; then the block, in hand, is carried over its goal as the whole chain's approach carries
        it (``tasks/carry.py``). An Insert state of its own keeps its goal, and its wrist holds the palm as the saved
        episode did (:func:`~seqdex_drake.tasks.carry.restore_held_orientation`)."""
        if from_task and from_task != self.config.name:
            self.place_goal(env, env.np_random, env.target_object)
            carry_to_goal(env)
        else:
            restore_held_orientation(env)

    def place_goal(self, env, rng, name: str) -> None:
        """Stands a plate of 1-3 layers on the baseplate (frozen) and declares block ``name``'s goal on it: a
        stud-aligned cell at a yaw of ``goal_yaws_deg``."""
        block_type = int(name.split("_")[1])
        layers = int(rng.integers(1, 4))
        env.objects.set_pose(env.context, f"plate_{layers}",
                             RigidTransform([*PLATE_XY, BASEPLATE_TOP]), frozen=True)
        yaw = float(rng.choice(np.deg2rad(self.config.goal_yaws_deg)))  # Default [0, 90]: 0 or pi / 2 exactly.
        nx, ny = BLOCK_SPECS[block_type].cells
        span = (ny, nx) if yaw % np.pi else (nx, ny)
        cell = (int(rng.integers(0, PLATE_CELLS - span[0] + 1)), int(rng.integers(0, PLATE_CELLS - span[1] + 1)))
        env.set_target(name, goal_pose(block_type, layers, cell, yaw))

    def goal_errors(self, env) -> tuple[float, float]:
        """:func:`block_goal_errors` of ``env``'s current state (position m, rotation rad)."""
        return block_goal_errors(env)

    def reward_terms(self, env, action):
        position, rotation = block_goal_errors(env)
        return goal_reward(self.config.reward, position, rotation, env.fingertip_distance(), action,
                           env.hand_torque())

    def is_success(self, env) -> bool:
        position, rotation = block_goal_errors(env)
        return position < self.config.success_threshold[0] and rotation < self.config.success_threshold[1]
