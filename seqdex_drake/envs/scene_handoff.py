"""Hand-offs between sub-tasks that train on different station scenes.

Forward initialization starts sub-task i+1 from sub-task i's successful terminal states. Where both run on one
scene (Orient and Grasp: the box with one block) the state is restored bit for bit. The Building Blocks sub-tasks
do not all share one: Search digs in the 72-block pile, Orient and Grasp train on one block in the box (coarse
collision pieces), Insert over the boards (fine pieces, the "similar" contact approximation), as the paper
trains them with different decompositions. A state handed across scenes carries over what the next sub-task
acts on: the robot (arm and hand positions, velocities and PD targets, the previous action), the target object
(the same object where the scene has it, else its counterpart of the same block type), its pose and velocity,
the goal and the simulation time. Every other object of the next scene is parked off the table. So Orient,
after Search, starts with the dug-out block on its own in the box: the pile around it does not come along.
(The whole-chain scene, ``building_blocks/chain``, keeps every block; ``results/building_blocks.md`` reports the
chain there.)

:func:`capture` adds the carried fields to a state an env saves (``SubtaskEnv.get_state``); :func:`restore`
applies a state from another scene (``SubtaskEnv.set_state``, for states whose plant size differs from the env's).
"""

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialVelocity

from seqdex_drake.env_state import EnvState, SceneHandoffError, counterpart


def capture(env, state: EnvState) -> EnvState:
    """``state`` (just saved by ``env``) with the robot's and the target object's positions and velocities set."""
    state.robot_positions = np.r_[env.plant.GetPositions(env.plant_context, env.arm),
                                  env.plant.GetPositions(env.plant_context, env.hand)]
    state.robot_velocities = np.r_[env.plant.GetVelocities(env.plant_context, env.arm),
                                   env.plant.GetVelocities(env.plant_context, env.hand)]
    if env.target_object:
        body = env.object_body()
        X_WB = env.plant.GetFreeBodyPose(env.plant_context, body)
        state.target_positions = np.r_[X_WB.rotation().ToQuaternion().wxyz(), X_WB.translation()]
        state.target_velocities = env.plant.EvalBodySpatialVelocityInWorld(env.plant_context, body).get_coeffs()
    return state


def check_carried(state: EnvState, num_positions: int, scenario: str) -> None:
    """Raises :class:`SceneHandoffError` unless ``state``, saved on a scene whose plant has another size than
    ``num_positions`` (``scenario``'s), carries the robot and target fields a hand-off across scenes needs."""
    if np.size(state.robot_positions) != 23 or (state.target_object and np.size(state.target_positions) != 7):
        raise SceneHandoffError(
            f"this state was saved on a scene with {np.size(state.plant_positions)} plant positions, this env's "
            f"({scenario}) has {num_positions}, and it lacks the robot and target fields a hand-off across scenes "
            f"needs (saved by an older version?); collect the terminal buffer again")


def restore(env, state: EnvState) -> None:
    """Puts ``env`` in ``state`` saved on another scene: the robot and the target object carried over, every other
    object parked (see the module docstring). The caller then restores the command sources (PD targets, previous
    action) and the sampled outputs, as for a state of its own scene. Raises :class:`SceneHandoffError` for a
    state without the carried fields or a target with no counterpart here."""
    check_carried(state, env.plant.num_positions(), env.config.scenario)
    env.context.SetTime(float(state.time))
    env.objects.park(env.context)
    env.objects.forget_motion()
    robot_q, robot_v = np.asarray(state.robot_positions, float), np.asarray(state.robot_velocities, float)
    env.plant.SetPositions(env.plant_context, env.arm, robot_q[:7])
    env.plant.SetPositions(env.plant_context, env.hand, robot_q[7:])
    env.plant.SetVelocities(env.plant_context, env.arm, robot_v[:7])
    env.plant.SetVelocities(env.plant_context, env.hand, robot_v[7:])
    if state.target_object:  # (Every sub-task declares one; a state without it carries the robot only.)
        name = counterpart(state.target_object, env.objects.names)
        q = np.asarray(state.target_positions, float)
        X_WB = RigidTransform(Quaternion(q[:4] / np.linalg.norm(q[:4])), q[4:])
        env.objects.set_pose(env.context, name, X_WB, frozen=False)
        body = env.objects.bodies[env.objects.index(name)]
        env.plant.SetFreeBodySpatialVelocity(env.plant_context, body,
                                             SpatialVelocity(np.asarray(state.target_velocities, float)))
        env.set_target(name, state.goal)
