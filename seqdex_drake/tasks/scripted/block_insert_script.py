"""A scripted demonstrator for the Building Blocks ``insert`` sub-task (put the held block on its goal, studs
seated), acting only through the env's 19-dim action space; the base of the budget variant's residual policy
(``tasks/insert.py`` ``budget_config``, ``tasks/residual.py``).

The reset (``tasks/handoff.py`` ``scripted_block_pickup``) leaves the block pinched across its 3 cm width, the index
and middle tips on its +x face (world), the thumb on its -x face, about 2 cm above its bottom, the block at yaw
pi/2 + 0.05..0.1 and leaning 0.13 rad about its long axis (world y). The wrist action is translation only, so the
block cannot be turned: the budget config draws yaw-90 goals only. The action is a function of the observation and
the step only (:meth:`ScriptedBlockInsert.act`, no hidden state); the budget observation carries the step as
step / 125.

* Hand. Steps 0-99 it keeps the reset's grasp: at step 0 its joint targets are read off the observation by the PD
  law, ``q + (tau + kd dq) / kp`` (joint positions, velocities and motor torques; to 2e-4 rad), from step 1 on
  they are the previous applied action's hand part (the observation's entries 124-139). From step 100 it lets go,
  by the grasp in hand (:data:`TRIPOD_THUMB_ROTATION`). Its own reset's tripod opens over 6 steps by
  :data:`RELEASE_DELTA` added to those targets: each tip 2 cm off its face and 1 cm up (inverse kinematics on the
  hand alone); then it holds. Opening to the open hand instead straightens the thumb, whose tip then pushes the
  block along +x (see below). Any other grasp (Grasp's jaw pinch, in a hand-off from Grasp) relaxes: the targets
  go to the measured joint positions, and the lift slides the tips off the block. From the 60 Grasp hand-offs of
  ``runs/building_blocks_seqdex/buffers/grasp_to_insert.npz`` (carried over the goal, ``tasks/carry.py``
  ``carry_to_goal``) the script placed 31 opening by RELEASE_DELTA, whose index and middle tips pushed into the
  jaw-held block, and 39 relaxing; relaxing the tripod placed none of seeds 0-29 (the tripod's opening is what
  straightens the block's 0.13 rad lean as it drops). Jaw-held blocks fail mostly by rolling 15-50 deg in the
  pinch when one end meets a stud; on the first 30 of those hand-offs (22 / 30 as the script is) neither a slower
  descent (``descend_rate`` 0.15: 20 / 30), a firmer pinch (0.1 rad more on the flexion targets at step 0:
  5 / 30; 0.2 rad: 0 / 30), nor stopping the downward command within 2.2 cm of the goal while the palm does not
  follow it (the wrist target winds up while the block rests on a stud: 22 / 30, and 23 / 30 on Insert's own
  seeds 0-29 as without) helped.
* Wrist (steps 0-99): ``clip((gain * (target - block) - damping * palm displacement per step) / 0.005)`` on the
  observed block origin (the centre of its bottom; the goal-minus-object entries), so the block, not the palm,
  goes to the goal whatever its offset in the hand; the clip ramps from 1/8 to 1 over the first 8 steps (no jerk
  on the grasp). The target is the goal's xy at ``hover`` (3 cm) above the goal until the block is within
  ``descend_xy`` (0.8 mm) of it in xy, then a funnel (15 m per m of xy error) down to ``seat`` (1.5 cm above the
  goal: the plate's studs, 2 cm tall, are 5 mm inside the block), at most 2 mm per step downward. The seat is
  not lower because the fingertip spheres, 6-12 mm above the block's bottom beside it, land on the studs of the
  neighbouring cells there. Steps 100-111 the wrist holds; from 112 it lifts ([0, 0, 1]), 6.5 cm by the end. The
  transit is the long part: the block starts at y = 0.12 m and the goals lie at y = -0.29..-0.17, 60-80 steps at
  the wrist's 0.3 m/s. A block not in hand (:meth:`ScriptedBlockInsert.holds`: farther than 8 cm from the tips'
  centroid, about 3 cm in the pinch) is not steered: the wrist holds. The law would otherwise drive the hand on
  without end after a block that never follows (a failed Grasp before Insert in the whole chain). In the env the
  rule never acts on a held block: the 300 episodes below (seeds 0, 1000, 2000), the script alone and the trained
  residual on it, gave the same outcome and return each with the rule as without.
* The release does the seating: the open block falls the last 1.5 cm guided by the studs already in it, and
  flattens its 0.13 rad lean and its yaw error on the studs' chamfers (seated to < 1 mm where the plate stays
  put).
* A grasp that relaxes (Grasp's jaw pinch) lets go as soon as the block is down at the seat
  (:meth:`ScriptedBlockInsert.released`, ``seated_dz``), and the wrist lifts once the block has dropped onto the
  studs (``settled_h``), rather than at steps 100 and 112. A block carried over its goal (the chain's hand-offs)
  reaches the seat within about 30 steps, and held there until step 100 it turned in the jaws as the studs
  pressed on it: in most of the misses on 40 tuning hand-offs (``seqdex collect --task grasp ... --seed 400000``)
  its tilt grew from 3-5 deg at step 30 to 11-27 deg at step 99, and it ended tilted on the studs. Letting go at
  the seat: 35 / 40 against 28 (``seated_dz`` 0.001-0.003 gave 35, 0.004 38, 0.006 32, 0.01 14: the lowest kept).
  On 60 held-out hand-offs (seed 500000) x plate seeds 0 / 1000 / 2000, the same 180 episodes in each row: the
  script 160 against 141 (21 / 2, McNemar p = 7e-5), with the shipped residual 152 against 142 (13 / 3, p = 0.02;
  that residual was trained with the timed release).

Measured in the budget env with the residual at zero (``seqdex rollout --task insert --zero-action --episodes 100
--seed S --out results/building_blocks/insert_script_seedS.json``): 84 / 100 on seeds 0-99, 80 / 100 on seeds
1000-1099, 83 / 100 on seeds 2000-2099: 247 / 300 (0.82 +- 0.02), none terminated, no simulator error, with the
plates held as fixtures (``freeze.never_wake`` in the Insert scenario; cause 1 below). Before that fix 79 / 77 /
83 (239 / 300; by plate height 1 layer 89 / 91, 2 layers 80 / 96, 3 layers 70 / 113; by block type 1x2 40 / 56,
curved 1x2 40 / 49, 1x2 soft curve 42 / 64, 1x3 64 / 70, 1x4 53 / 61). About 3.3 s of CPU per episode (the
reset's simulated pickup included). Equivalently ``measure(range(30), make_env("insert", budget_config("insert")))``.

Tuning (seeds 0-9 unless said; each change kept the ones before): wrist gain 0.4, damping 1.0, descent within 2
mm at 10 m/m from 3.5 cm to 1.2 cm, the hand opened at once to the open hand at step 100, lift from 106: 6 / 10;
the hand opening toward the open hand at 0.1 rad per step: 0 / 10 (the straightening thumb pushes the block +x
off the studs, and the lift flips it); :data:`RELEASE_DELTA` at step 96, lift from 110, seat 1.5 cm, descent at
most 0.4: 7 / 10; gain 0.5, damping 0.5 (the xy error converged slowly, 3 mm -> 1.2 mm in 15 steps, and the
descent began off-centre), descent within 0.8 mm at 15 m/m from 3 cm, release 100, lift 112: 8 / 10 and 17 / 20 on
seeds 10-29 (the script as it is). Never raising the wrist once the block is among the studs: 12 / 20 on seeds
0-19 (worse: the block stays jammed on the studs it hit, tilted).

Failure causes seen. (1) The plate woke up (fixed since: the Insert scenario's plates never wake): ``tasks/insert.py``
places the plate frozen on the baseplate, but the
freezer's wake check (``scene/objects.py``, within 9 cm of the hand or touched by it or by the moving block)
makes it a free body, and its solid bottom, placed through the baseplate's 2 cm studs, is then pushed up out of
them: 1-layer plates wake as the hand comes over them and rise 5 mm by the episode's end, 3-layer plates wake
when touched and rise 1.5 cm in 25 steps, carrying the block off its goal (every 3-layer failure; 3-layer
successes end 1.5-1.8 cm high). With the plates re-pinned after every step (a diagnosis harness, not the env)
the script does 18 / 20 on seeds 0-19, blocks seated to < 1 mm. (2) The block's lean and yaw error put its ribs
on the studs' tops instead of between them (1.6 cm above the goal, the xy error about 1 mm); the wrist law then
lifts it back to the hover height as it tips, and the release at step 100 drops it from 2.4 cm, tilted, onto the
stud tops (seeds 2 and 12 with the plates pinned). (3) Opening the hand drags the block if the thumb straightens
(the first versions).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from seqdex_drake.observation_layout import FINGERTIPS, GOAL_POSITION_ERROR, MOTOR_TACTILE, PREVIOUS_ACTION
from seqdex_drake.robots.allegro import (
    ALLEGRO_Q_MAX,
    ALLEGRO_Q_MIN,
    scale_action_to_limits,
    unscale_limits_to_action,
)
from seqdex_drake.tasks.scripted.scripted_episode import play_script

WRIST_STEP = 0.005
"""Metres per step of the hand centre at wrist action 1 (the env's ``wrist_step``)."""
CONTROL_RATE = 60.0
"""Policy steps per second (the env's control period is 1/60 s)."""

JOINT_Q = slice(7, 23)
"""The 16 Allegro joint positions in the observation (after the 7 Franka joints)."""
JOINT_V = slice(30, 46)
"""The 16 Allegro joint velocities in the observation."""
PREVIOUS_HAND = slice(PREVIOUS_ACTION.start, PREVIOUS_ACTION.start + 16)
"""The hand part of the previous applied action."""
GOAL_POSITION = slice(159, 162)
"""The goal position of the block's origin (the centre of its bottom rim)."""
PALM_VELOCITY = slice(105, 108)
"""The palm's linear velocity."""

RELEASE_DELTA = np.array([0.0, -0.065, -0.111, -0.097, 0.0, -0.069, -0.111, -0.096, 0.0, 0.0, 0.0, 0.0,
                          0.14, 0.0, -0.405, 0.573])
"""Joint increments [rad] of the release, added to the reset's grasp targets: the index and middle tips 2 cm off
the block's face (along world +x) and 1 cm up, the thumb's tip 2 cm off along -x and 1 cm up (damped Newton on the
hand alone, ``tasks/scripted/grasping.MakeHandPlant``, joints 1-3, 5-7 and 12, 14, 15; thumb joint 13 is at its lower
limit
in the grasp). Opened with the thumb straightened instead, the thumb's tip moves toward +x: into the block."""


THUMB_ROTATION = 13
"""The thumb's joint 13 (its rotation toward the fingers) among the 16 hand joints."""
TRIPOD_THUMB_ROTATION = 0.1
"""The release tells the grasp in hand by the thumb's joint 13 [rad]: below this, Insert's own tripod (the reset's
squeeze holds it at about -0.05, near its lower limit -0.105), which opens by :data:`RELEASE_DELTA`; above it any
other grasp, e.g. Grasp's jaw pinch (0.3-0.4) in a hand-off from Grasp, which relaxes: its joint targets go to the
measured joint positions (no grip force, no finger motion) and the wrist's lift slides the tips up off the block.
Opened by RELEASE_DELTA, the jaw pinch's index and middle tips push into the block's far face."""


class ScriptedBlockInsert:
    """The scripted insertion (see the module docstring): :meth:`act` of the observation and the step only.

    Args:
        hover: height of the block's bottom above its goal while it is carried over the plate [m].
        seat: height of the block's bottom above its goal where it is held before the release [m].
        release_at: the hand opens from this step on.
        lift_at: the wrist lifts ([0, 0, 1]) from this step on.
        ramp: the wrist speed ramps up over the first ``ramp`` steps.
        gain, damping: the wrist law's proportional gain and velocity damping.
        descend_xy, funnel: the descent starts within ``descend_xy`` [m] of the goal in xy; above, the target
            height rises ``funnel`` m per m of xy error (up to ``hover``).
        hand_kp, hand_kd: the hand's PD gains (the scenario's ``robot.hand_kp``, ``hand_kd``), to read the
            hand's joint targets off the observation at the first step.
        held_reach: the block counts as in hand within this distance of the tips' centroid [m] (:meth:`holds`).
        wrist_step: the env's ``wrist_step`` [m per step at action 1].
        release: how the hand lets go: "tripod" (:data:`RELEASE_DELTA`), "relax" (the targets to the measured
            joints), or "auto": by the grasp in hand (:data:`TRIPOD_THUMB_ROTATION`).
        seated_dz: a grasp that relaxes lets go as soon as the block's bottom is within this [m] of the seat
            height (the funnel only lets it that low centred on its goal), without waiting for ``release_at``;
            None: at ``release_at`` only (:meth:`released`).
        settled_h: after such a release the wrist lifts once the block's bottom is within this [m] of its goal
            (dropped onto the studs), without waiting for ``lift_at`` (:meth:`lifting`).
    """

    def __init__(self, hover=0.03, seat=0.015, release_at=100, lift_at=112, ramp=8, gain=0.5, damping=0.5,
                 descend_xy=0.0008, funnel=15.0, descend_rate=0.4, open_steps=6, hand_kp=3.0, hand_kd=0.1,
                 held_reach=0.08, wrist_step=WRIST_STEP, release="auto", seated_dz=0.001, settled_h=0.004):
        self.hover, self.seat, self.release_at, self.lift_at, self.ramp = hover, seat, release_at, lift_at, ramp
        self.gain, self.damping, self.descend_xy, self.funnel = gain, damping, descend_xy, funnel
        self.descend_rate, self.open_steps = descend_rate, open_steps
        self.hand_kp, self.hand_kd, self.wrist_step = hand_kp, hand_kd, wrist_step
        self.held_reach = held_reach
        if release not in ("auto", "tripod", "relax"):
            raise ValueError(f"release must be 'auto', 'tripod' or 'relax', got {release!r}")
        self.release = release
        self.seated_dz, self.settled_h = seated_dz, settled_h

    def reset(self, env) -> None:
        pass

    def held_hand_action(self, observation, step: int) -> np.ndarray:
        """The hand action that keeps the hand's current joint targets."""
        o = observation
        if step > 0:
            return np.asarray(o[PREVIOUS_HAND], float)
        q = np.asarray(o[JOINT_Q], float) + (np.asarray(o[MOTOR_TACTILE], float) + self.hand_kd * np.asarray(
            o[JOINT_V], float)) / self.hand_kp
        return unscale_limits_to_action(np.clip(q, ALLEGRO_Q_MIN, ALLEGRO_Q_MAX))

    def holds(self, observation) -> bool:
        """Whether the block is in hand: its origin within ``held_reach`` of the index, middle and thumb tips'
        centroid (about 3 cm in the pinch). A block dropped (or never grasped: a failed Grasp before it in a chain)
        is not steered after: the wrist law would drive the hand on without end, as the block never follows."""
        o = np.asarray(observation, dtype=float)
        tips = o[FINGERTIPS].reshape(4, 13)[[0, 1, 3], :3]
        block = o[GOAL_POSITION] - o[GOAL_POSITION_ERROR]
        return float(np.linalg.norm(tips.mean(axis=0) - block)) <= self.held_reach

    def release_kind(self, observation) -> str:
        """How the hand lets go (``release="auto"``: by the grasp in hand, see :data:`TRIPOD_THUMB_ROTATION`)."""
        if self.release != "auto":
            return self.release
        return "tripod" if observation[JOINT_Q][THUMB_ROTATION] < TRIPOD_THUMB_ROTATION else "relax"

    def _height(self, observation) -> float:
        """The block's bottom (its origin) above its goal [m]."""
        return float(-np.asarray(observation, float)[GOAL_POSITION_ERROR][2])

    def released(self, observation, step: int) -> bool:
        """Whether the hand lets go at ``step``: from ``release_at`` on, and a grasp that relaxes (Grasp's jaw pinch)
        as soon as the block is down at the seat (why: the module docstring). Once the block is that low it only
        drops further, so the test stays true and the action stays a function of (observation, step)."""
        if step >= self.release_at:
            return True
        return self.seated_dz is not None and self.release_kind(observation) == "relax" and \
            self._height(observation) <= self.seat + self.seated_dz

    def lifting(self, observation, step: int) -> bool:
        """Whether the wrist lifts at ``step``: from ``lift_at`` on, and after an early release (:meth:`released`)
        once the block has dropped to within ``settled_h`` of its goal (below the seat: released there already)."""
        if step >= self.lift_at:
            return True
        return self.seated_dz is not None and self.release_kind(observation) == "relax" and \
            self._height(observation) <= min(self.settled_h, self.seat + self.seated_dz)

    def block_target(self, observation) -> np.ndarray:
        """Where the block's origin should go now (world) [m]."""
        o = np.asarray(observation, float)
        goal = o[GOAL_POSITION]
        error = o[GOAL_POSITION_ERROR]
        d_xy = float(np.linalg.norm(error[:2]))
        z = goal[2] + max(self.seat, min(self.hover, self.seat + self.funnel * (d_xy - self.descend_xy)))
        return np.r_[goal[:2], z]

    def act(self, observation, step: int) -> np.ndarray:
        """The action for ``observation`` (the env's, 173 or 174 entries) at ``step``."""
        o = np.asarray(observation, dtype=float)
        released = self.released(o, step)
        if released:  # The release, by the grasp in hand (release_kind).
            if self.release_kind(o) == "relax":
                hand_action = unscale_limits_to_action(np.clip(o[JOINT_Q], ALLEGRO_Q_MIN, ALLEGRO_Q_MAX))
            else:
                last = scale_action_to_limits(o[PREVIOUS_HAND])
                opening = RELEASE_DELTA / self.open_steps if step < self.release_at + self.open_steps else 0.0
                hand_action = unscale_limits_to_action(np.clip(last + opening, ALLEGRO_Q_MIN, ALLEGRO_Q_MAX))
        else:
            hand_action = self.held_hand_action(o, step)
        if self.lifting(o, step):
            wrist = np.array([0.0, 0.0, 1.0])
        elif released or not self.holds(o):  # Released, or nothing in hand: the wrist holds.
            wrist = np.zeros(3)
        else:
            block = o[GOAL_POSITION] - o[GOAL_POSITION_ERROR]
            velocity = o[PALM_VELOCITY] / CONTROL_RATE
            limit = min(1.0, (step + 1) / self.ramp)
            wrist = np.clip((self.gain * (self.block_target(o) - block) - self.damping * velocity) / self.wrist_step,
                            -limit, limit)
            wrist[2] = max(wrist[2], -self.descend_rate)
        return np.clip(np.r_[hand_action, wrist], -1.0, 1.0)

    def action(self, env, step: int) -> np.ndarray:
        return self.act(env.observation(), step)


@dataclasses.dataclass
class Episode:
    """What :func:`run_episode` saw."""

    success: bool
    """The env's ``info["success"]`` at the last step."""
    position_error: float
    """The block's distance to its goal at the end [m]."""
    rotation_error: float
    """The block's rotation to its goal (a yaw flip counting as the goal) at the end [rad]."""


def run_episode(env, seed: int, controller: ScriptedBlockInsert | None = None, wrist_noise: float = 0.0,
                rng: np.random.Generator | None = None) -> Episode:
    """One episode of the scripted insertion from ``env.reset(seed=seed)``. In an env with a residual base (the
    budget env) the env applies the script and this sends zero corrections; otherwise it sends ``controller``'s
    actions (default :class:`ScriptedBlockInsert`). ``wrist_noise``: the standard deviation of Gaussian noise
    added to the 3 wrist entries of what is sent (a residual policy's exploration)."""
    info, _, _ = play_script(env, seed, controller or ScriptedBlockInsert(), wrist_noise, rng)
    return Episode(bool(info["success"]), *env.task.goal_errors(env))  # The Insert task's own errors.


def measure(seeds, env, controller: ScriptedBlockInsert | None = None, wrist_noise: float = 0.0) -> dict:
    """Per-seed success of the scripted insertion over ``seeds`` (the env's own ``info["success"]`` at the end)
    in ``env``, e.g. the budget env ``make_env("insert", budget_config("insert"))`` (the script is the residual
    base, the corrections zero)."""
    return {seed: run_episode(env, seed, controller, wrist_noise).success for seed in seeds}
