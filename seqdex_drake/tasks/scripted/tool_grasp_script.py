"""A scripted demonstrator for the ``tool_grasp`` sub-task (pick the hammer up), acting only through the env's
19-dim action space.

Phase rules (as the trained policies are run): steps 0-59 free; steps 60-89 the wrist action is exactly
[0, 0, 1] (a 0.15 m lift) while the fingers may still move; from step 90 on the wrist action is [0, 0, 0] and the
hand targets are those of step 89.

Strategy: a fist around the handle near the head, with the curled thumb as a backstop. The action is a function
of the observation and the step only (:meth:`ScriptedToolGrasp.act`; no hidden integrators), so that behaviour
cloning can reproduce it: the geometry is recomputed from the observed hammer pose every step, the wrist is a
proportional-derivative law on the observed hand centre, and the thumb's progress is read back from the previous
action in the observation.

* Geometry. The hammer rests on its striking face with the handle inclined down to the table. Grasp point A is
  the handle axis at tool y = ``ya`` (0.10; the centre of mass is at 0.1246, the head at 0.172). The hand centre
  goal puts A at ``(hx, c, hz)`` in the palm frame: ``hx`` 4.5 cm (the palm nearly resting on the handle), on the
  index side (``c``) so the head lies beyond the index finger, and ``hz`` 8.1 cm from the wrist plate, behind
  the knuckles.
* Wrist (steps 0-59): ``clip((gain * (target - hand) - damping * palm displacement per step) / 0.005)``, gain 0.4
  (saturated only beyond about 1.2 cm of error), the damping on the observed palm velocity (no overshoot in
  spite of the arm's lag). The target is the goal's xy and a funnel in z: the hover height (0.785 m, above the
  head's peen) until the hand is within ``descend_xy`` of the goal in xy *and* the thumb is curled, then down to
  the goal. The env integrates the command into its wrist target, so this law has no steady-state error.
* Thumb. Straight, flat at its lower rotation limit until the hand is within ``thumb_xy`` (2.5 cm) of the goal in
  xy, at the hover height; then it curls (1/6 of the way per step, read back from the previous action) into a ball
  near the wrist. Curling it lower hits the hammer.
* Fingers (from step 42, 20 steps; timed by the step, which the budget observation carries as step/150). Every
  finger follows the same joint path: curl the middle and distal joints into a hook (6 steps), then close around
  the handle (14 steps), ``squeeze`` past the contact shape. A per-finger path chosen by where the handle crosses
  each finger (as an earlier version did) made a turning handle change the paths and feed its own rotation.
* Lift (steps 60-89, wrist [0, 0, 1], fingers finishing) and hold (90-149: the previous hand targets, wrist 0).

Measured (``measure(range(30), make_env("tool_grasp"))``, seeds 0-29): 12 / 30 = 40 % success (seeds 1, 2, 8, 11, 12,
18, 19, 20, 22,
24, 25, 26); 11 / 20 on seeds 1000-1019. About 1 s per episode on a shared core (the env's own step time
dominates). The previous, integral-corrected version reached 4 / 30.

Behaviour cloning (``behaviour_clone``, 50 epochs, 25 demonstrations from seeds 0-60, action MSE 0.009; the clone
rolled out deterministically in the budget env): 1 / 12 on seeds where the script succeeds (1-26 above) and
2 / 20 on seeds 1000-1019 (the previous version's clone: 0). Still poor: the clone either knocks the hammer over
during the approach or closes an empty hand. The success is sensitive to the hand's pose at the closing (a
palm 5 mm lower, ``hx`` 0.040, gives 1 / 30; ``hz`` +-6 mm gives 5-10 / 30), so a clone's centimetre-level
errors remain fatal, and the thumb's curl (a step-by-step increment on the previous action, started by a
threshold on the xy distance) and the hover-height gate are discontinuities a small network smooths over.

Failure causes of the script: rotation in the fist while it closes and lifts (the fist pulls the handle toward
the wrist and lines it up across the fingers, costing about |yaw| for tools far from yaw 0), and the hammer
knocked over for large positive yaw (the head ends up on the wrist side, where the curled thumb is).

What would probably help next: choose the grasp point / offset by yaw so the head stays clear of the thumb for
positive yaw; a thumb curl driven continuously by the hand's height and xy error rather than an increment; close
with the palm resting on the handle; more demonstrations with perturbed starts (DART-style noise injection) so
the clone sees and learns the corrections.
"""

from __future__ import annotations

import numpy as np

from seqdex_drake.observation_layout import rotation_matrix
from seqdex_drake.robots.allegro import (
    ALLEGRO_Q_MAX,
    ALLEGRO_Q_MIN,
    p_PalmHc_Palm,
    scale_action_to_limits,
    unscale_limits_to_action,
)

FREE_STEPS, LIFT_STEPS, EPISODE_STEPS = 60, 30, 150
WRIST_STEP = 0.005
"""Metres per step of the hand centre at wrist action 1 (the env's ``wrist_step``)."""

HOOK = np.array([0.0, 0.6, 1.6])
FIST = np.array([1.0, 1.26, 1.04])
"""Flexion-joint path (joints 1-3) of every finger: straight -> ``HOOK`` (middle and distal joints curled) ->
``FIST`` (plus ``squeeze``, so the fingers press on). From a grid search over a planar model of the finger
(links 0.054, 0.0384, 0.060 m, radius 0.011 m, knuckle at palm z 0.111 m) for a handle crossing the finger's plane
at palm z 0.07: the fingertips stay above the table and touch the handle late. The same path for every finger and
every yaw: choosing it by where the (turning) handle crosses each finger made the closing feed its own rotation."""

THUMB_FLAT = np.array([ALLEGRO_Q_MIN[12], ALLEGRO_Q_MIN[13], 0.0, 0.0])
"""Thumb during the approach: at its lower rotation limit and straight, in the palm's plane."""

THUMB_CURLED = np.array([ALLEGRO_Q_MIN[12], ALLEGRO_Q_MAX[13], ALLEGRO_Q_MAX[14], ALLEGRO_Q_MAX[15]])
"""Thumb from the end of the xy move: curled into a ball near the wrist, a backstop behind the handle."""

STARTED = 0.1
"""Thumb progress above which the curl counts as started (it goes on, whatever the hand's distance). Without
noise the progress is 0 or at least 1 / 6; under a residual policy's exploration noise the read-back progress of a
flat thumb is a little above 0, and a test for > 0 would start the curl at once."""

CURLED = 0.9
"""Thumb progress from which the thumb counts as curled (the descent may start). Without noise the progress steps
through k / 6, so this is the full curl; under a residual policy's exploration noise the read-back progress of a
full curl sits just below 1, and a test for exactly 1 would keep the hand hovering for good."""

CONTROL_RATE = 60.0
"""Policy steps per second (the env's control period is 1/60 s)."""


class ScriptedToolGrasp:
    """The scripted hammer pickup (see the module docstring): ``action(env, step)`` for steps 0-149 after
    ``env.reset`` (``reset(env)`` is kept for the controller interface; there is no state to reset). The action is
    :meth:`act` of the env's current observation: a function of the observation and the step only."""

    def __init__(self, ya=0.10, c=0.035, hx=0.045, hz=0.081, z_up=0.785, close_at=42, n1=6, n2=14,
                 gain=0.4, damping=1.0, descend_xy=0.012, funnel=10.0, thumb_xy=0.025, park_steps=6,
                 squeeze=(0.2, 0.2, 0.2)):
        self.ya, self.c, self.hx, self.hz, self.z_up = ya, c, hx, hz, z_up
        self.close_at, self.n1, self.n2 = close_at, n1, n2
        self.gain, self.damping, self.descend_xy, self.funnel = gain, damping, descend_xy, funnel
        self.thumb_xy, self.park_steps = thumb_xy, park_steps
        self.fist = np.minimum(FIST + np.asarray(squeeze, float), ALLEGRO_Q_MAX[1:4])

    def reset(self, env) -> None:
        pass

    def goal_and_hand(self, observation) -> tuple[np.ndarray, np.ndarray]:
        """The hand-centre goal (from the hammer's observed pose) and the observed hand centre, world [m]."""
        o = observation
        A = np.asarray(o[111:114], float) + rotation_matrix(o[114:118]) @ [0.0, self.ya, -0.0115]  # On the handle axis.
        # Palm frame at the held orientation: x = world -z, y = world y, z = world x; the hand centre Hc is at
        # palm (0.04, 0, 0.13). A at palm (hx, c, hz) <=> Hc = A + (0.13 - hz, -c, hx - 0.04).
        goal = A + np.array([0.13 - self.hz, -self.c, self.hx - 0.04])
        hand = np.asarray(o[98:101], float) + rotation_matrix(o[101:105]) @ p_PalmHc_Palm
        return goal, hand

    def act(self, observation, step: int) -> np.ndarray:
        """The action for ``observation`` (the env's, 159 or 160 entries) at ``step``."""
        o = np.asarray(observation, dtype=float)
        previous = o[124:143]  # The previous applied action.
        if step >= FREE_STEPS + LIFT_STEPS:  # Hold: the hand targets of step 89 (the env freezes them anyway).
            return np.r_[previous[:16], 0.0, 0.0, 0.0]
        goal, hand = self.goal_and_hand(o)
        d_xy = float(np.linalg.norm(goal[:2] - hand[:2]))
        # Thumb: curls at park_steps per full curl once the hand is within thumb_xy of the goal in xy; its
        # progress is read back from the previous action.
        q_previous = scale_action_to_limits(previous[:16])
        s = 0.0 if step == 0 else float(np.clip((q_previous[13] - THUMB_FLAT[1]) / (THUMB_CURLED[1] - THUMB_FLAT[1]),
                                                0.0, 1.0))
        if step < FREE_STEPS:
            # Down a funnel: at the hover height z_up until within descend_xy in xy and the thumb is curled.
            z = max(goal[2], min(self.z_up, goal[2] + self.funnel * (d_xy - self.descend_xy)))
            if s < CURLED:
                z = max(z, self.z_up)
            velocity = np.asarray(o[105:108], float) / CONTROL_RATE  # Palm displacement per step.
            error = np.r_[goal[:2], z] - hand
            wrist = np.clip((self.gain * error - self.damping * velocity) / WRIST_STEP, -1.0, 1.0)
        else:
            wrist = np.array([0.0, 0.0, 1.0])
        if s > STARTED or d_xy < self.thumb_xy:
            s = min(1.0, s + 1.0 / self.park_steps)
        thumb = THUMB_FLAT + (THUMB_CURLED - THUMB_FLAT) * s
        k = step - self.close_at + 1
        if k <= 0:
            finger = np.zeros(3)
        elif k <= self.n1:
            finger = HOOK * k / self.n1
        else:
            finger = HOOK + (self.fist - HOOK) * min(1.0, (k - self.n1) / self.n2)
        q = np.r_[np.tile(np.r_[0.0, finger], 3), thumb]
        hand_action = unscale_limits_to_action(np.clip(q, ALLEGRO_Q_MIN, ALLEGRO_Q_MAX))
        return np.clip(np.r_[hand_action, wrist], -1.0, 1.0)

    def action(self, env, step: int) -> np.ndarray:
        return self.act(env.raw_observation(), step)


def run_episode(env, seed: int, controller: ScriptedToolGrasp | None = None):
    """One episode of the scripted pickup. Returns (success, actions (150, 19))."""
    controller = controller or ScriptedToolGrasp()
    env.reset(seed=seed)
    controller.reset(env)
    actions, info = [], {"success": False}
    for step in range(EPISODE_STEPS):
        a = controller.action(env, step)
        actions.append(a)
        _, _, terminated, truncated, info = env.step(a)
        if terminated or truncated:
            break
    return bool(info["success"]), np.array(actions)


def measure(seeds, env, controller: ScriptedToolGrasp | None = None) -> float:
    """Success rate of the scripted pickup over ``seeds`` in ``env`` (a tool Grasp env, e.g.
    ``make_env("tool_grasp")``; the env's own ``info["success"]`` at the end)."""
    seeds = list(seeds)
    return sum(run_episode(env, s, controller)[0] for s in seeds) / len(seeds)
