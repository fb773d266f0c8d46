"""A scripted demonstrator for the Building Blocks ``orient`` sub-task (stand a lying block upright in the box),
acting only through the env's 19-dim action space; the base of the budget variant's residual policy
(``tasks/orient.py`` ``budget_config``, ``tasks/residual.py``).

Strategy: roll the block about its long axis with one fingertip, a quarter turn at a time. The hand cannot turn
(palm down, fingers along world +x, wrist translation only), but it can move a fingertip in any direction: the
middle finger is hooked down as a stylus (``STYLUS_Q``; the other fingers folded out of its way) and the wrist
moves it. The block's roll about its long axis (:func:`roll_angle`, from the observed orientation) says where it
is: upright (0), on a long side (+-90 deg) or upside down (180 deg), and which way is up for it: turning it by
-roll about its body x stands it up, which moves its top along a horizontal direction e (across its long axis).

* On a long side: the tip presses on the top face ``inset`` in from its edge on the e side (the open bottom's)
  and strokes along e at a fixed height (``press`` below the face, the floor being the box's), 3 mm per step.
  Friction drags the top along e and the block pivots on its bottom edge on that side (fingertip on block 0.82
  beats block on box floor 0.58, Drake's combined coefficients), its studs rising; the tip slides across the
  face as the block turns under it, and from about 30 deg before upright the block falls upright by itself.
* Upside down (resting on its studs, narrow): the tip dips into the open bottom against the wall on the e side and
  strokes along e: the block tips onto that side (about 12 deg is enough) and lies on its side with the same e,
  and the side stroke follows. The tip's height follows the observed rim while the block is within
  ``follow_rim_above`` of upside down (the curved types 2 and 3 rest pitched on their one stud and curved top, the
  rim 2 cm lower than a brick's), then stays fixed. Either way would do; the script rolls it toward +x (more
  strongly within ``near_wall_x`` of the near wall) and toward the box's centre line.
* Upright (within ``upright_below``): the tip moves straight away from the block to ``release`` from its centre,
  then up until the fingertip is ``lift`` above its top, and holds.

Each step the script recomputes the zone, the stroke's start and direction from the observed block pose, and
whether the tip (its position from the observed palm pose and the free finger's offset) is at the start and
may stroke: within ``tolerance`` across e and in height, and not past the start by more than the roll so far
allows. Otherwise it approaches: over the start at ``clearance`` above the block's top, rising before moving
across, then down a funnel. So the action is a function of the observation and the step only
(:meth:`ScriptedBlockOrient.act`, no hidden state; the step times only the hand's forming, steps 5-12), and a
stroke that slips off is simply made again. A side-lying block stands at about step 30 and the fingertip ends
4 cm above it; an upside-down one stands at about step 55 (55-65 for the curved types) and the episode (75 steps,
the release's) ends with the fingertip moved about 2 cm clear of its side, rising.

Measured in the budget env with the residual at zero (``seqdex rollout --task orient --zero-action --episodes
100 --seed S --out results/building_blocks/orient_script_seedS.json``, or ``measure(range(S, S + 100),
make_env("orient", budget_config("orient")))``; deterministic): 92 / 100 on seeds 0-99, 86 / 100 on 1000-1099,
86 / 100 on 2000-2099, i.e. 0.88 +- 0.03 (264 / 300); seeds 0-29 alone (``--episodes 30``): 29 / 30. About 1.5 s per
episode on a shared core. Tuned on seeds 0-29 and 100-129 (57 / 60 there); 1000-1099 and 2000-2099 are held out.

What was tried (on seeds 0-29 unless said): a target fixed on the block with a lead along e (the tip slid to
its target and stalled, or slid off the edge into the open bottom and rolled the block the wrong way) 2-6 / 8;
the same with the tip's observed position as feedback (the finger's deflection under the press, 1 cm along x
for the first stylus shape, drove the wrist backward and dragged the block the wrong way) 0-3 / 8; a target
offset by the finger's compliance times a desired contact force (the offsets came out at 1-4 mm, within the
model's errors, and the finger hardly pressed) 0-1 / 5; then the constant-speed stroke (above) at 4 mm per step
23 / 30 with the first stylus (middle finger tip 12.5 cm below and 17 cm ahead of the wrist) and the open thumb,
28 / 30 with the zones, the release and the folded thumb, 55 / 60 on seeds 0-29 and 100-129, and 57 / 60 at
3 mm per step (at 4 mm a 1x4 near the far side stalled at its balance point and fell back; the 3 left were
blocks by the near wall). Releasing at 25 deg without moving away first, or lifting while the tip touched the
standing block, toppled it over the other edge; a rim-following hook for every upside-down block (not only near
rest) slowed the flat bricks' first roll.

Failure causes seen in the 36 failures of the 300: 18 blocks at x < 0.13 m (within 18 cm of the near wall's
inner face): the tip is 15 cm ahead of the wrist, and a stroke toward -x there puts the palm into the wall, so
the roll stops; 8 upside-down curved blocks (types 2 and 3, resting pitched) that roll onto a side late or tip
back, ending mid-roll at step 75; 6 upside-down bricks (types 1, 4, 5) that tip back or over; 4 side-lying
blocks, 2 of them stood up and then toppled over the other edge as the tip moved away. No episode ended in a
simulator error or with the block out of the box.

In the whole pile (Search's 58 hand-offs, ``seqdex rollout --task orient --zero-action --scene
building_blocks/search``) it stands 10 / 58 up, 4 of them upright already. The
strokes' heights assume the box floor under the block; taking the block's lowest point instead (it often lies on
other blocks) stood 6 / 58 up: the stroke's start on the e side is mostly taken by a neighbour as high as the
block or higher, which stops the fingertip above the face (traced) and would stop the roll anyway.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from seqdex_drake.observation_layout import rotation_matrix
from seqdex_drake.robots.allegro import (
    ALLEGRO_OPEN_Q,
    ALLEGRO_Q_MAX,
    ALLEGRO_Q_MIN,
    FINGERTIP_RADIUS,
    unscale_limits_to_action,
)
from seqdex_drake.scene.piles import BOX_CENTER
from seqdex_drake.tasks.scripted.scripted_episode import play_script

WRIST_STEP = 0.005
"""Metres per step of the hand centre at wrist action 1 (the env's ``wrist_step``)."""
CONTROL_RATE = 60.0
"""Policy steps per second (the env's control period is 1/60 s)."""
BLOCK_WIDTH = 0.03
"""Width (body y extent) of every training block [m] (``modeling/blocks.py``)."""
TOTAL_HEIGHT = 0.0575
"""Height of a block with its studs [m]."""
HALF_LENGTH = 0.06
"""Half the length of the longest training block (1x4) [m]: the block's extent along its long axis, for its top."""

STYLUS_Q = np.array([0.0, -0.196, -0.174, -0.227, 0.0, 0.2, 0.8, 1.2, 0.0, -0.196, -0.174, -0.227,
                     1.396, -0.105, 0.27, -0.16])
"""The working hand [rad]: the middle finger hooked down (its distal phalanx pointing down and back), the index
and ring fingers bent back to their limits, the thumb turned under the palm (its tip 4 cm below the palm, 4.4 cm
to +y). Every other part of the hand is at least 5 cm above the middle tip, and the hand is 5.5 cm wide in +y
instead of the open thumb's 8.8 cm."""
p_PalmTip_Palm = np.array([0.0924, 0.0, 0.1479])
"""The middle fingertip's centre in the palm frame, the hand at ``STYLUS_Q`` and free [m]: 9 cm below the palm,
15 cm ahead of the wrist (measured in the env; the kinematics say 1 mm less, the finger sags)."""


def roll_angle(R_WB: np.ndarray) -> float:
    """The block's roll about its long axis (body x) [rad]: 0 upright, +-pi/2 on a long side (+ with its body +y
    up), +-pi upside down. Turning the block by -roll about its body x stands it up."""
    up_B = R_WB[2]  # World z in the body frame (the last row of R_WB).
    return math.atan2(up_B[1], up_B[2])


@dataclasses.dataclass
class Plan:
    """What the script does about the block in one observation."""

    zone: str
    """"upright" (move away and up), "side" (roll it up from a long side) or "upside_down" (onto a side)."""
    start: np.ndarray
    """Where the stroke starts: the middle tip's centre, world [m] (the block's footprint centre if upright)."""
    direction: np.ndarray
    """The stroke's horizontal direction e (unit, world): the block's top moves this way as it rolls."""
    allowance: float
    """How far past ``start`` along e the tip may be while stroking, for the roll so far [m]."""
    top: float
    """The block's highest point (world z) [m]."""
    rolling: bool = False
    """Whether the block has left its resting pose (a roll under way): the stroke then goes on further."""


class ScriptedBlockOrient:
    """The scripted block Orient (see the module docstring): :meth:`act` of the observation and the step only;
    ``action(env, step)`` for steps after ``env.reset`` (``reset(env)`` is kept for the controller interface; there
    is no state to reset).

    Args:
        press: the side stroke's depth below the lying block's top face [m].
        inset: the side stroke starts this far in from the top face's edge on the e side [m].
        hook_offset, hook_height: the upside-down stroke starts ``hook_offset`` in from the e side wall, the tip's
            centre ``hook_height`` above the open bottom's rim [m] (the tip dips into the cavity).
        stroke: the wrist action along e while stroking (0.8: 4 mm per step).
        upright_below, side_below: the zones' bounds on the roll's magnitude [rad].
        release: once upright, the tip moves to this horizontal distance from the block's centre before it lifts
            (to ``lift`` above the block's top) [m].
        clearance: the approach's height above the block's top, tip surface to top [m].
        tolerance, height_tolerance: how near the start (across e, and in height) the tip must be to stroke [m].
        funnel: the approach descends ``funnel`` m per m of horizontal error.
        roll_travel, slack, rolling_slack: the stroke's allowance past its start: ``roll_travel`` m per rad rolled,
            plus ``slack``, plus ``rolling_slack`` once the roll is under way.
        follow_rim_above: the upside-down stroke's height follows the rim while the roll's magnitude is above
            this [rad]; below, the rim's height at rest on flat studs.
        prefer_x, near_wall_x: weight of +x against "toward the box's centre line" when the script picks the way
            to roll an upside-down block (either way works), four times that for a block at world x below
            ``near_wall_x`` [m].
        shape_at, shape_steps: the hand goes from open to ``STYLUS_Q`` over these steps.
        gain, damping: the wrist law's proportional gain and velocity damping.
        wrist_step: the env's ``wrist_step`` [m per step at action 1].
    """

    def __init__(self, press=0.004, inset=0.012, hook_offset=0.006, hook_height=0.007, stroke=0.6,
                 upright_below=0.35, side_below=1.75, release=0.05, lift=0.04, clearance=0.02, tolerance=0.006,
                 height_tolerance=0.006, funnel=1.5, roll_travel=0.035, slack=0.012, rolling_slack=0.03,
                 follow_rim_above=2.6, prefer_x=0.5, near_wall_x=0.16, shape_at=5, shape_steps=8, gain=0.4,
                 damping=1.0, wrist_step=WRIST_STEP):
        self.press, self.inset, self.hook_offset, self.hook_height = press, inset, hook_offset, hook_height
        self.stroke, self.upright_below, self.side_below = stroke, upright_below, side_below
        self.release, self.lift, self.clearance = release, lift, clearance
        self.tolerance, self.height_tolerance, self.funnel = tolerance, height_tolerance, funnel
        self.roll_travel, self.slack, self.rolling_slack = roll_travel, slack, rolling_slack
        self.prefer_x, self.shape_at, self.shape_steps = prefer_x, shape_at, shape_steps
        self.gain, self.damping, self.wrist_step = gain, damping, wrist_step
        self.follow_rim_above, self.near_wall_x = follow_rim_above, near_wall_x

    def reset(self, env) -> None:
        pass

    def hand_q(self, step: int) -> np.ndarray:
        """The hand's joint targets at ``step`` (open, then to ``STYLUS_Q``)."""
        s = min(1.0, max(0.0, (step - self.shape_at + 1) / self.shape_steps))
        return ALLEGRO_OPEN_Q + (STYLUS_Q - ALLEGRO_OPEN_Q) * s

    def plan(self, observation) -> Plan:
        """The zone, stroke start and direction for the block pose in ``observation``."""
        o = observation
        R_WB = rotation_matrix(o[114:118])
        p_WB = np.asarray(o[111:114], float)
        roll = roll_angle(R_WB)
        corners = np.array([[x, y, z] for x in (-HALF_LENGTH, HALF_LENGTH) for y in (-BLOCK_WIDTH / 2, BLOCK_WIDTH / 2)
                            for z in (0.0, TOTAL_HEIGHT)])
        heights = p_WB[2] + corners @ R_WB[2]
        top, floor = float(np.max(heights)), BOX_CENTER[2]
        across = np.cross(R_WB[:, 0], [0.0, 0.0, 1.0])
        across /= max(float(np.linalg.norm(across)), 1e-9)
        if abs(roll) < self.upright_below:
            return Plan("upright", p_WB, across, 0.0, top)
        if abs(roll) > math.radians(170.0):  # Upside down: either way; +x (room for the hand), to the box's centre.
            toward_centre = 1.0 if BOX_CENTER[1] > p_WB[1] else -1.0
            prefer_x = self.prefer_x if p_WB[0] > self.near_wall_x else 4.0 * self.prefer_x  # Away from the wall.
            sign = -1.0 if across[0] * prefer_x + across[1] * toward_centre > 0 else 1.0
        else:
            sign = 1.0 if roll > 0 else -1.0
        e = -sign * across  # Turning by -roll about body x moves the top along e.
        if abs(roll) >= self.side_below:  # The tip in the open bottom, against the wall on the e side.
            start = p_WB + R_WB @ np.array([0.0, -sign * (BLOCK_WIDTH / 2 - self.hook_offset), 0.0])
            rim = min(floor + TOTAL_HEIGHT, p_WB[2]) if abs(roll) > self.follow_rim_above else floor + TOTAL_HEIGHT
            start[2] = rim + self.hook_height
            allowance = self.roll_travel * (math.pi - abs(roll)) + self.slack
            return Plan("upside_down", start, e, allowance, top, abs(roll) < math.radians(170.0))
        # On the top face (the side facing up), ``inset`` in from its edge on the e side (the open bottom's).
        start = p_WB + R_WB @ np.array([0.0, sign * BLOCK_WIDTH / 2, self.inset])
        start[2] = floor + BLOCK_WIDTH + FINGERTIP_RADIUS - self.press
        allowance = self.roll_travel * (math.pi / 2 - abs(roll)) + self.slack
        return Plan("side", start, e, allowance, top, abs(roll) < math.radians(80.0))

    def act(self, observation, step: int) -> np.ndarray:
        """The action for ``observation`` (the env's, 159 or 160 entries) at ``step``."""
        o = np.asarray(observation, dtype=float)
        hand_action = unscale_limits_to_action(np.clip(self.hand_q(step), ALLEGRO_Q_MIN, ALLEGRO_Q_MAX))
        # Where the tip would be, free.
        tip = np.asarray(o[98:101], float) + rotation_matrix(o[101:105]) @ p_PalmTip_Palm
        velocity = np.asarray(o[105:108], float) / CONTROL_RATE  # Palm displacement per step.
        plan = self.plan(o)
        if plan.zone == "upright":  # Away from the block (radially, to ``release``), then up.
            away = tip[:2] - plan.start[:2]
            distance = float(np.linalg.norm(away))
            goal_xy = tip[:2] if distance >= self.release else plan.start[:2] + away * self.release / max(distance,
                                                                                                          1e-6)
            clear = distance >= self.release - 0.01 or tip[2] > plan.top + FINGERTIP_RADIUS
            goal = np.r_[goal_xy, plan.top + FINGERTIP_RADIUS + self.lift if clear else tip[2]]
            return np.r_[hand_action, self._wrist(goal, tip, velocity)]
        error = plan.start - tip
        e = plan.direction
        along = -float(error @ e)  # How far the tip is past the start along e.
        lateral = error[:2] - (error[:2] @ e[:2]) * e[:2]
        formed = step >= self.shape_at + self.shape_steps
        reach = plan.allowance + (self.rolling_slack if plan.rolling else 0.0)
        if (formed and abs(error[2]) < self.height_tolerance and float(np.linalg.norm(lateral)) < self.tolerance
                and -self.tolerance < along < reach):  # Stroke: along e at the start's height.
            wrist = self._wrist(plan.start, tip, velocity)
            wrist[:2] = self.gain * lateral / self.wrist_step + self.stroke * e[:2]
            return np.clip(np.r_[hand_action, wrist], -1.0, 1.0)
        goal = plan.start.copy()  # Approach: over the start, then down a funnel.
        d_xy = float(np.linalg.norm(error[:2]))
        z_safe = plan.top + FINGERTIP_RADIUS + self.clearance
        goal[2] = z_safe if not formed else max(goal[2], min(z_safe, goal[2] + self.funnel * (d_xy - self.tolerance)))
        wrist = self._wrist(goal, tip, velocity)
        if d_xy > 2 * self.tolerance and (tip[2] < min(goal[2], z_safe) - self.height_tolerance
                                          or tip[2] < plan.top + FINGERTIP_RADIUS):
            wrist[:2] *= 0.2  # Rise before moving across (not to drag the block along).
        return np.clip(np.r_[hand_action, wrist], -1.0, 1.0)

    def _wrist(self, goal, tip, velocity) -> np.ndarray:
        return np.clip((self.gain * (goal - tip) - self.damping * velocity) / self.wrist_step, -1.0, 1.0)

    def action(self, env, step: int) -> np.ndarray:
        return self.act(env.observation(), step)


@dataclasses.dataclass
class Episode:
    """What :func:`run_episode` saw."""

    success: bool
    """The env's ``info["success"]`` at the last step."""
    up_z: float
    """The block's body z axis's world z at the end (1 upright; success above 0.6)."""
    clearance: float
    """The middle fingertip's gap to the block at the end, above its top or beside its long side [m] (the hand
    off the block: it stands free)."""


def run_episode(env, seed: int, controller: ScriptedBlockOrient | None = None) -> Episode:
    """One episode of the scripted Orient from ``env.reset(seed=seed)``. In an env with a residual base (the
    budget env) the env applies the script and this sends zero corrections; otherwise it sends ``controller``'s
    actions (default :class:`ScriptedBlockOrient`)."""
    controller = controller or ScriptedBlockOrient()
    info, _, _ = play_script(env, seed, controller)
    o = env.observation()
    plan, R_WB = controller.plan(o), rotation_matrix(o[114:118])
    across = np.cross(R_WB[:, 0], [0.0, 0.0, 1.0])
    beside = abs(float((o[59:61] - o[111:113]) @ across[:2])) / max(float(np.linalg.norm(across)), 1e-9)
    clearance = max(float(o[61]) - plan.top, beside - BLOCK_WIDTH / 2) - FINGERTIP_RADIUS
    return Episode(bool(info["success"]), float(R_WB[2, 2]), clearance)


def measure(seeds, env, controller: ScriptedBlockOrient | None = None) -> dict:
    """Per-seed success of the scripted Orient over ``seeds`` (the env's own ``info["success"]`` at the end) in
    ``env``, e.g. the budget env ``make_env("orient", budget_config("orient"))`` (the script is the residual base,
    the corrections zero)."""
    return {seed: run_episode(env, seed, controller).success for seed in seeds}
