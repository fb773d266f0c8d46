"""Tool Reorient (Tool Positioning): turn the held tool to its ready-to-use pose, head facing down.

Reset: a hand-off state from tool Grasp (``options={"initial_state": ...}``), or standalone the hammer
settled, by simulation, in a fist (power) grasp of its handle with the palm down (``tasks/handoff.py``,
:func:`~seqdex_drake.tasks.handoff.synthesized_tool_grasp`; only the hammer has one), the handle's yaw across
the palm drawn from the episode's rng (+-0.1 rad: the start, and so the goal, vary with the seed). The hand's PD
targets are then the fist: hand actions are absolute targets, so a policy keeps holding with
:func:`~seqdex_drake.tasks.handoff.hold_action`, while the zero action opens the hand to mid-range. Goal: the
start pose flipped 180 deg about the tool's long axis y (FACTS.md), at the same place. Observation: base +
goal (173).
Reward: the paper's In-hand Orientation formula. Success: orientation error below 0.5 rad (FACTS.md) with the
tool still held, its origin within ``HELD_DISTANCE`` of the goal's (the paper: "lifted and held in hand in a
ready-to-use pose"); a tool farther than that has left the hand (dropped or thrown): task failure, the episode
terminates. The hand-off lifts the tool more than 0.1 m off the table, so a dropped tool fails this test before it
lands; a 180 deg roll about the handle moves the origin by about 2 cm (it sits 1.2 cm off the handle's axis).
The tool must also be lifted (``tools_common.HELD_LIFT`` above its resting height), as the whole chain judges it:
from a hand-over before tool Grasp's lift is done (the switcher's early hand-overs) a roll in place near the table
is not the task, and F, fitted on this success, must learn that.

:func:`budget_config` is the variant that fits a small training budget (``../shared/TRAINING.md``): a residual
policy (``tasks/residual.py``) on the searched finger gait of ``tasks/scripted/tool_reorient_gait.py``, which rolls the
held
hammer about its handle; the policy corrects the wrist (3 dims), and the episode's progress is in the observation
(the gait is timed; 174 entries).
"""

import dataclasses

from pydrake.math import RigidTransform, RotationMatrix

from seqdex_drake.observation_layout import pose_vector
from seqdex_drake.tasks.base import Task, TaskConfig
from seqdex_drake.tasks.handoff import synthesized_tool_grasp
from seqdex_drake.tasks.rewards import RewardWeights, goal_errors, goal_reward
from seqdex_drake.tasks.tools_common import is_lifted, tool_name

#: How far (m) the tool's origin may be from the goal's (its hand-off position) while held.
HELD_DISTANCE = 0.1


def default_config() -> TaskConfig:
    return TaskConfig(
        name="tool_reorient", scenario="tool_positioning/tool_reorient", episode_length=125, ema=1.0,
        object_types=[0], reward=RewardWeights(progress=1.0, fingertip=0.0, action=-0.001, torque=-0.003,
                                               alpha0=20.0, alpha1=1.0, e0=0.06),
        success_threshold=[0.5])  # [orientation error (rad)]


def budget_config() -> TaskConfig:
    """The small-budget variant: a residual on the searched finger gait that corrects the wrist (the gait's fingers
    apply as they are: exploration noise of std 0.1 on all 19 dims cut the gait's success from 0.54 to a training
    rate of 0.09-0.13, as finger noise broke tool Grasp's scripted fist), with the episode's progress observed."""
    return dataclasses.replace(default_config(), residual="tool_reorient_gait", observe_time=True, hand_actions=False)


class ToolReorientTask(Task):
    """Flip a held tool head-down."""

    goal = True

    def reset(self, env, rng) -> None:
        name = tool_name(int(rng.choice(env.config.object_types)))
        env.objects.park(env.context)
        env.set_target(name)
        synthesized_tool_grasp(env, name, rng)
        self.on_restore(env)

    def on_restore(self, env, from_task: str = "") -> None:
        """The goal: the tool's current pose flipped 180 deg about its long axis y, in place (kept when the
        state is this task's own, e.g. a mid-episode state restored exactly)."""
        if from_task == self.config.name:
            return
        X_WT = env.object_pose()
        goal = RigidTransform(X_WT.rotation() @ RotationMatrix.MakeYRotation(3.141592653589793), X_WT.translation())
        env.set_target(env.target_object, pose_vector(goal))

    def reward_terms(self, env, action):
        position, rotation = goal_errors(env.observation_values())
        return goal_reward(self.config.reward, position, rotation, env.fingertip_distance(), action,
                           env.hand_torque())

    def is_success(self, env) -> bool:
        position, rotation = goal_errors(env.observation_values())
        return rotation < self.config.success_threshold[0] and position < HELD_DISTANCE and is_lifted(env)

    def is_failure(self, env) -> bool:
        """The tool left the hand: its origin is more than ``HELD_DISTANCE`` from the goal's, or below the
        config's drop height."""
        return goal_errors(env.observation_values())[0] > HELD_DISTANCE or super().is_failure(env)
