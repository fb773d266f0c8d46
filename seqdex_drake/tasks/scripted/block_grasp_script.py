"""A scripted demonstrator for the Building Blocks ``grasp`` sub-task (lift an upright block out of the box),
acting only through the env's 19-dim action space; the base of the budget variant's residual policy
(``tasks/grasp.py`` ``budget_config``, ``tasks/residual.py``).

Phase rules (``tasks/phases.py`` ``release_block_grasp_phases``): steps 0-74 free; from step 75 to the end the
wrist action is exactly [0, 0, 1] (the scripted lift) while the hand stays the script's.

Strategy: a jaw pinch along world x, the one direction the hand can squeeze in (the palm is held down with the
fingers along world +x, and the wrist action is translation only, so the hand cannot turn to the block's yaw).
The index and middle tips are one jaw, on the block's far side, the thumb tip the other, on its near side; they
close toward each other on a line through the grasp centre C (palm (0.08, 0.012, 0.165), 8 cm below the palm).
Whatever the yaw, the closing jaws turn the block until a face lies flat against the two fingertips, most often
the long face (the 3 cm width pinched), sometimes an end face (a 6 cm block pinched along its length), and it
holds for every training type (1x2, the two curved 1x2-footprint blocks, 1x3, 1x4): the block's type is not in
the observation and the script does not need it. The action is a function of the observation and the step only
(:meth:`ScriptedBlockGrasp.act`, no hidden state): the geometry is recomputed from the observed block pose every
step, and the hand follows a schedule in the step (the env's step count; the budget observation carries it as
step / 150).

* Wrist (steps 0-31): ``clip((gain * (target - hand) - damping * palm displacement per step) / 0.005)`` on the
  observed hand centre, gain 0.4, as ``tasks/scripted/tool_grasp_script.py``. The goal puts C over the block's footprint
  centre (its body origin, whatever the type), ``depth`` (2.2 cm) above its bottom; for a block in the box its x
  is held at least at ``x_min`` (0.085 m): nearer the box's near wall (x = -0.05 m) the hand and the arm meet the
  wall, so a block there is pinched off-centre, nearer the thumb (outside the box, on the staging area, no
  bound). The target's height is ``z_up`` (12.5 cm above the block's bottom: the curled jaws clear the studs)
  until the pre-grasp shape is formed and the hand is within ``descend_xy`` of the goal in xy, then a funnel down
  to the goal. Steps 32-47 the wrist holds (0); from step 48
  it lifts ([0, 0, 1]): the block clears 0.30 m at about step 108 (success from there to the end; the phases'
  lift alone, from step 75, would reach it near step 135) and ends about 0.50 m up.
* Hand. Open for steps 0-3, then (steps 4-11) to the pre-grasp shape: jaws 7 cm either side of C, i.e. 14 cm
  apart (a 1x4 block along x fits between them), at C's depth. From step 32 the jaws close over 14 steps through
  shapes 5.5, 4, 2.5 and 1 cm from C (inverse kinematics on the hand alone, the ring finger straight), then
  ``squeeze`` (0.1 rad) further on every flexion joint: past contact, so the PD presses the block (the hand's
  gains make the press compliant, and a wider block simply stops the jaws earlier). The thumb cannot reach nearer
  the wrist than about palm z 0.09 at this depth, which bounds the opening.

Measured in the budget env with the residual at zero (``seqdex rollout --task grasp --zero-action --episodes 30
--seed 0``, or ``measure(range(30), make_env("grasp", budget_config("grasp")))``):
30 / 30 on seeds 0-29, 30 / 30 on held-out seeds 1000-1029 and 30 / 30 on seeds 100-129; under the budget
residual's initial exploration noise (Gaussian, std 0.1, on the 3 wrist corrections; ``measure(range(30), env,
wrist_noise=0.1)``) 30 / 30. About 2 s per episode on a shared core. ``seqdex rollout --task grasp --zero-action``
runs it over more episodes (``results/building_blocks.md``). Earlier versions: C at palm z 0.15 with the jaws
forming at the start height 0 / 10 (the thumb swept onto the block's top and toppled it); C at 0.165 without
``x_min`` 21 / 30 (every block nearer than x = 0.11 m out of reach); ``squeeze`` 0.2 instead of 0.1 25 / 30 on
seeds 100-129.

Failure causes seen while tuning (``x_min``, ``depth`` and ``squeeze`` were chosen on seeds 0-29 and 100-129):
blocks near the box's far wall (x > 0.41 m), where the reset's hover pose put the open hand's straight fingertips
(0.146 m beyond the hand centre) inside the wall, and near the near wall (x < 0.08 m), where it put the palm in
the wall: no action frees either, and resets no longer sample there (``tasks/blocks_common.sample_box_xy``);
with them 28 / 30 on seeds 0-29. A block near the near wall (x < 0.1 m) is pinched off-centre near the thumb
(the hand's x is held at ``x_min``) and can tip over as the jaws close. With ``squeeze`` 0.2 a 1x2-footprint
block with its length along x tilted in the length pinch (an index tip rode over its end) and fell in the lift.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from seqdex_drake.observation_layout import rotation_matrix
from seqdex_drake.robots.allegro import (
    ALLEGRO_OPEN_Q,
    ALLEGRO_Q_MAX,
    ALLEGRO_Q_MIN,
    p_PalmHc_Palm,
    unscale_limits_to_action,
)
from seqdex_drake.scene.piles import BOX_CENTER, BOX_INNER_HALF
from seqdex_drake.tasks.scripted.scripted_episode import play_script

WRIST_STEP = 0.005
"""Metres per step of the hand centre at wrist action 1 (the env's ``wrist_step``)."""
CONTROL_RATE = 60.0
"""Policy steps per second (the env's control period is 1/60 s)."""

p_PalmC_Palm = np.array([0.08, 0.012, 0.165])
"""The grasp centre C in the palm frame [m]: 8 cm in front of the palm (below it, palm down), midway between the
index and middle fingers' planes, 0.165 m from the wrist (the tripod grasp centre of ``tasks/scripted/grasping.py``)."""

_JAW_FINGERS = {
    0.070: [0.098, 0.242, 0.299, 0.387, 0.0, 0.246, 0.303, 0.39],
    0.055: [0.151, 0.167, 0.402, 0.526, 0.0, 0.151, 0.421, 0.553],
    0.040: [0.171, 0.046, 0.562, 0.748, 0.0, 0.036, 0.577, 0.769],
    0.025: [0.196, -0.016, 0.686, 0.91, 0.0, -0.02, 0.7, 0.928],
    0.010: [0.229, -0.035, 0.791, 1.035, 0.0, -0.035, 0.805, 1.051],
}
"""Index and middle joints (0-7) with both tips at palm (0.08, 0.012 +- 0.015, 0.165 + h), keyed by h [m]: inverse
kinematics on the hand alone (``tasks/scripted/grasping.MakeHandPlant``), each shape from the previous as initial guess,
to 3 mm."""

_JAW_THUMB = {
    0.070: [0.852, -0.105, 0.223, 1.595],
    0.055: [0.852, -0.105, 0.131, 1.505],
    0.040: [0.86, -0.105, 0.081, 1.352],
    0.025: [0.86, -0.016, 0.067, 1.065],
    0.010: [0.86, 0.144, 0.063, 0.649],
}
"""Thumb joints (12-15) with its tip at palm (0.08, 0.012, 0.165 - h), keyed by h [m] (as ``_JAW_FINGERS``)."""

CLOSING = [np.r_[_JAW_FINGERS[h], ALLEGRO_OPEN_Q[8:12], _JAW_THUMB[h]] for h in sorted(_JAW_FINGERS, reverse=True)]
"""Hand shapes of the closing, jaws 7 cm from C (the pre-grasp) to 1 cm (past contact on a 3 cm face)."""

_FLEXION = [1, 2, 3, 5, 6, 7, 13, 14, 15]
"""The joints ``squeeze`` adds to: the index, middle and thumb flexion joints."""


def _path(points: list[np.ndarray], s: float) -> np.ndarray:
    """Piecewise-linear interpolation through ``points`` at ``s`` in [0, 1]."""
    s = min(max(s, 0.0), 1.0) * (len(points) - 1)
    k = min(int(s), len(points) - 2)
    return points[k] + (points[k + 1] - points[k]) * (s - k)


class ScriptedBlockGrasp:
    """The scripted block pickup (see the module docstring): :meth:`act` of the observation and the step only;
    ``action(env, step)`` for steps 0-149 after ``env.reset`` (``reset(env)`` is kept for the controller interface;
    there is no state to reset).

    Args:
        depth: height of C above the block's bottom at the grasp [m].
        z_up: height of the hand centre above the block's bottom while the pre-grasp forms [m].
        pre_at, pre_steps: the pre-grasp shape forms over steps ``pre_at .. pre_at + pre_steps - 1``.
        close_at, close_steps: the jaws close over steps ``close_at .. close_at + close_steps - 1``.
        squeeze: added to the flexion joints of the last closing shape [rad].
        lift_at: the script lifts the wrist ([0, 0, 1]) from this step on.
        x_min: the hand-centre goal's least world x [m] for a block in the box (its near wall); a block outside
            the box (the staging area) is pinched at its centre.
        gain, damping: the wrist law's proportional gain and velocity damping.
        descend_xy, funnel: the descent starts within ``descend_xy`` [m] of the goal in xy; above, the target
            height rises ``funnel`` m per m of xy error (up to ``z_up``).
        wrist_step: the env's ``wrist_step`` [m per step at action 1].
    """

    def __init__(self, depth=0.022, z_up=0.125, pre_at=4, pre_steps=8, close_at=32, close_steps=14, squeeze=0.1,
                 lift_at=48, x_min=0.085, gain=0.4, damping=1.0, descend_xy=0.006, funnel=10.0,
                 wrist_step=WRIST_STEP):
        self.depth, self.z_up, self.pre_at, self.pre_steps = depth, z_up, pre_at, pre_steps
        self.close_at, self.close_steps, self.lift_at, self.x_min = close_at, close_steps, lift_at, x_min
        self.gain, self.damping, self.descend_xy, self.funnel = gain, damping, descend_xy, funnel
        self.wrist_step = wrist_step
        squeezed = CLOSING[-1].copy()
        squeezed[_FLEXION] += squeeze
        self.closing = CLOSING + [np.clip(squeezed, ALLEGRO_Q_MIN, ALLEGRO_Q_MAX)]

    def reset(self, env) -> None:
        pass

    def goal_and_hand(self, observation) -> tuple[np.ndarray, np.ndarray]:
        """The hand-centre goal (C over the block's footprint centre, ``depth`` above its bottom; x at least
        ``x_min``) and the observed hand centre, world [m]."""
        o = observation
        R_WP = rotation_matrix(o[101:105])
        goal = np.asarray(o[111:114], float) + [0.0, 0.0, self.depth] - R_WP @ (p_PalmC_Palm - p_PalmHc_Palm)
        if np.all(np.abs(o[111:113] - BOX_CENTER[:2]) <= BOX_INNER_HALF):  # Only the box has a near wall.
            goal[0] = max(goal[0], self.x_min)
        return goal, np.asarray(o[98:101], float) + R_WP @ p_PalmHc_Palm

    def hand_q(self, step: int) -> np.ndarray:
        """The hand's joint targets at ``step`` (open, to the pre-grasp, closing, squeezed)."""
        if step < self.close_at:
            return ALLEGRO_OPEN_Q + (self.closing[0] - ALLEGRO_OPEN_Q) * min(1.0, max(0.0, (
                step - self.pre_at + 1) / self.pre_steps))
        return _path(self.closing, (step - self.close_at + 1) / self.close_steps)

    def act(self, observation, step: int) -> np.ndarray:
        """The action for ``observation`` (the env's, 159 or 160 entries) at ``step``."""
        o = np.asarray(observation, dtype=float)
        hand_action = unscale_limits_to_action(np.clip(self.hand_q(step), ALLEGRO_Q_MIN, ALLEGRO_Q_MAX))
        if step >= self.lift_at:
            wrist = np.array([0.0, 0.0, 1.0])
        elif step >= self.close_at:
            wrist = np.zeros(3)
        else:
            goal, hand = self.goal_and_hand(o)
            d_xy = float(np.linalg.norm(goal[:2] - hand[:2]))
            z_up = float(o[113]) + self.z_up
            z = z_up if step < self.pre_at + self.pre_steps else max(
                goal[2], min(z_up, goal[2] + self.funnel * (d_xy - self.descend_xy)))
            velocity = np.asarray(o[105:108], float) / CONTROL_RATE  # Palm displacement per step.
            wrist = np.clip((self.gain * (np.r_[goal[:2], z] - hand) - self.damping * velocity) / self.wrist_step,
                            -1.0, 1.0)
        return np.clip(np.r_[hand_action, wrist], -1.0, 1.0)

    def action(self, env, step: int) -> np.ndarray:
        return self.act(env.observation(), step)


@dataclasses.dataclass
class Episode:
    """What :func:`run_episode` saw."""

    success: bool
    """The env's ``info["success"]`` at the last step."""
    rise: float
    """The block's centre of mass at the end above its start [m]."""
    fingertip_distance: float
    """The env's fingertip distance sum at the end [m]."""


def run_episode(env, seed: int, controller: ScriptedBlockGrasp | None = None, wrist_noise: float = 0.0,
                rng: np.random.Generator | None = None) -> Episode:
    """One episode of the scripted pickup from ``env.reset(seed=seed)``. In an env with a residual base (the
    budget env) the env applies the script and this sends zero corrections; otherwise it sends ``controller``'s
    actions (default :class:`ScriptedBlockGrasp`). ``wrist_noise``: the standard deviation of Gaussian noise added
    to the 3 wrist entries of what is sent (a residual policy's exploration)."""
    info, _, _ = play_script(env, seed, controller or ScriptedBlockGrasp(), wrist_noise, rng)
    rise = float(env.object_position()[2]) - env.task.start_height  # The Grasp task's height at reset.
    return Episode(bool(info["success"]), rise, float(env.fingertip_distance()))


def measure(seeds, env, controller: ScriptedBlockGrasp | None = None, wrist_noise: float = 0.0) -> dict:
    """Per-seed success of the scripted pickup over ``seeds`` (the env's own ``info["success"]`` at the end) in
    ``env``, e.g. the budget env ``make_env("grasp", budget_config("grasp"))`` (the script is the residual base,
    the corrections zero). The env is the caller's: this module sits below the tasks, which use it as a base."""
    return {seed: run_episode(env, seed, controller, wrist_noise).success for seed in seeds}
