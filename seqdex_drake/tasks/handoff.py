"""Scripted hand-offs: in-hand initial states for Insert and tool Reorient when no forward-initialization
buffer is given.

The paper's point (Sec. 4.1) is that random in-hand states are not physically stable, so Insert starts from
Grasp's successful terminal states (forward initialization, ``options={"initial_state": ...}``). Standalone,
an Insert reset instead *simulates* a scripted tripod pickup (``seqdex_drake.tasks.scripted.grasping``): the block
stands on the table, the hand descends, squeezes with force-balanced targets and lifts it, a physically valid
grasp in about 140 control steps. Tool Reorient closes the hand into a fist around the hammer's handle and
lets the hammer settle in it (:func:`synthesized_tool_grasp`, a power grasp, its yaw across the palm drawn per
episode), about 90 control steps.
"""

import dataclasses

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

from seqdex_drake.modeling.blocks import BLOCK_SPECS
from seqdex_drake.observation_layout import floats
from seqdex_drake.robots.allegro import ALLEGRO_Q_MAX, ALLEGRO_Q_MIN, PALM_BODY, unscale_limits_to_action
from seqdex_drake.tasks.scripted.grasping import ExecuteGrasp, PlanTripodPickup, RampTargets, SolveTripodGrasp

#: Where Insert's scripted pickup takes the block from: the free table area beside the baseplate.
PICKUP_XY = np.array([0.22, 0.12])
TABLE_TOP = 0.6
CONTACT_HEIGHT = 0.02
GRASP_FORCE = 1.0


class EnvHarness:
    """The part of :class:`~seqdex_drake.harness.StationHarness` the scripted grasp uses, over an environment."""

    def __init__(self, env, wake: bool = True):
        self.env = env
        self.wake = wake
        self.objects = env.objects
        self.context = env.context
        self.scenario = env.scenario

    def set_targets(self, arm_q=None, hand_q=None) -> None:
        arm = self.env._arm_target if arm_q is None else floats(np.asarray(arm_q, dtype=float))
        hand = self.env._hand_target if hand_q is None else floats(np.asarray(hand_q, dtype=float))
        self.env._hand_target = hand
        self.env._set_sources(arm, hand, self.env._previous_action)

    def step(self, n: int = 1) -> None:
        for _ in range(n):
            self.env.simulator.AdvanceTo(self.context.get_time() + self.scenario.control_period)
            if self.wake:
                self.objects.update(self.context)


def scripted_pickup(env, name: str, p_WC: np.ndarray, width: float, lift: float = 0.12) -> None:
    """Runs a scripted tripod pickup of object ``name`` resting (dynamic) where it is, ending with it lifted.

    ``p_WC`` is the grasp centre (midway between the two gripped faces, ``width`` apart, whose normals must be
    along the palm's z: world x at the home orientation). Raises RuntimeError if the object was not lifted.
    """
    harness = EnvHarness(env)
    plant, plant_context = env.plant, env.plant_context
    palm = plant.GetBodyByName(PALM_BODY, env.hand)
    start_height = float(env.object_position()[2])
    env.set_robot(env.hover_arm(p_WC), env.hand_q())
    grasp = SolveTripodGrasp(width, spread=0.015 if width >= 0.03 else 0.0125)
    plan = PlanTripodPickup(plant, plant_context, grasp, p_WC, palm.EvalPoseInWorld(plant_context).rotation(),
                            force=GRASP_FORCE, kp=env.scenario.robot.hand_kp, lift=lift)
    ExecuteGrasp(harness, plan)
    RampTargets(harness, 60, arm=(plan.arm_grasp, plan.arm_lift))
    harness.step(10)
    if env.object_position()[2] < start_height + 0.5 * lift:
        raise RuntimeError(f"the scripted pickup of {name} failed; pass a hand-off buffer state instead")


def scripted_block_pickup(env, name: str, yaw_jitter: float, rng: np.random.Generator) -> None:
    """Stands block ``name`` on the table (0.03 m sides toward the palm, yaw jitter) and picks it up."""
    block_type = int(name.split("_")[1])
    X_WB = RigidTransform(RollPitchYaw(0.0, 0.0, np.pi / 2 + rng.uniform(-yaw_jitter, yaw_jitter)),
                          [*PICKUP_XY, TABLE_TOP + 0.0005])
    env.objects.set_pose(env.context, name, X_WB, frozen=False)
    scripted_pickup(env, name, X_WB @ np.array([0.0, 0.0, CONTACT_HEIGHT]), BLOCK_SPECS[block_type].footprint[1])


FIST_FINGER_OPEN = np.array([0.0, 1.45, 0.2, 0.2])
"""Index, middle and ring joints [rad] before the fist closes: the proximal phalanges bent down out of the palm
(to the palm's +x), the middle and distal straight on, leaving the handle's place under the palm face free."""

FIST_FINGER_CLOSED = np.r_[0.0, ALLEGRO_Q_MAX[1:4]]
"""Index, middle and ring PD targets [rad] of the fist: every flexion joint at its upper limit. The fingers
stop on the handle and, with their tips, on the palm face; the middle joints then push with the 0.7 N m effort
limit, the base and distal joints with 0.35-0.6 N m (PD stiffness 3 N m/rad)."""

FIST_THUMB = np.array([ALLEGRO_Q_MIN[12], ALLEGRO_Q_MAX[13], 1.0, 1.0])
"""Thumb joints and PD targets [rad] during a fist grasp: swung out to its lower rotation limit and flexed down,
behind the handle (2.4 cm clear of the hammer). The Allegro thumb cannot oppose a handle that runs across
the palm: its tip cannot reach the handle beyond the index finger (lower limit of joint 12), and in front of
the palm it would land on the curled fingers."""


@dataclasses.dataclass(frozen=True)
class FistGrasp:
    """A power grasp: the tool's handle across the palm face, the index, middle and ring fingers closed around
    it into a fist whose fingertips rest on the palm, the thumb parked (``FIST_THUMB``).

    The handle runs along the palm's -y (head beyond the ring finger, the thumb's side free for the butt),
    turned by ``yaw`` about the palm normal (butt toward the fingertips: diagonally across the palm as in a
    human power grasp, which keeps it off the thumb's base) and rolled by ``roll`` about its own axis. The tool
    frame is then ``R_PalmT = Rx(yaw) R0 Ry(roll)`` in the palm frame, where R0 puts the tool's x along the palm's
    -z, y along -y and z along -x (palm down: the hammer head's peen up, its striking face down).
    """

    p_TA: np.ndarray
    """Point A on the handle's axis, in the tool frame [m]."""
    p_PalmA: np.ndarray
    """Where A is placed, in the palm frame [m] (palm face at x = 0.0204, knuckles at z = 0.095)."""
    yaw: float
    """Handle direction about the palm's x [rad]."""
    roll: float
    """Rotation about the tool's y (the handle) [rad]."""

    def X_PalmT(self) -> RigidTransform:
        """Pose of the tool in the palm frame."""
        R0 = RotationMatrix(np.array([[0.0, 0.0, -1.0], [0.0, -1.0, 0.0], [-1.0, 0.0, 0.0]]))
        R = RotationMatrix.MakeXRotation(self.yaw) @ R0 @ RotationMatrix.MakeYRotation(self.roll)
        return RigidTransform(R, self.p_PalmA - R.matrix() @ self.p_TA)


#: Fist grasps synthesized for Tool Reorient. Hammer: the point of the handle's axis (z = -0.0115) level with the
#: centre of mass (y = 0.1246) goes 3.4 cm out from the palm's mid-plane (the handle 1.4 mm off the palm face),
#: 8.5 mm inside the ring finger (palm y = -0.0435) and 5 cm from the wrist plate; every finger is at least
#: 1.4 cm away until the fist closes. Yaw 0.35 rad: the handle clears the thumb's base. Roll 0.52 rad (the peen
#: leans 30 deg toward the wrist): the orientation the hammer settles to from roll 0 in this fist, so the release
#: transient stays small (0.08 rad, 1.2 cm).
TOOL_GRASPS = {"hammer": FistGrasp(p_TA=np.array([0.0, 0.1246, -0.0115]), p_PalmA=np.array([0.034, -0.035, 0.05]),
                                   yaw=0.35, roll=0.52)}

GRASP_YAW_JITTER = 0.1
"""Half-width [rad] of the uniform per-episode variation of a synthesized grasp's ``yaw`` (the handle's direction
across the palm, turned about point A; with the palm down, the tool's yaw in the world). Hammer: every yaw within
+-0.12 rad of the nominal grasp (scanned in 0.02 rad steps, and 20 seeds) settles and then holds to 0.5 mm and
0.02 rad over 1 s; the placement clears the hand by 1.4 mm at +-0.1 rad (0.9 mm at +0.12, inside it at +0.2),
and at -0.15 rad the hammer does not settle. Sliding the handle along its axis as well is not safe: with ``p_TA``
3 mm nearer the head, +0.08 rad already places the hammer touching the hand."""

FIST_CLOSE_TICKS = 20
FIST_HOLD_TICKS = 10
SETTLE_TICKS = 60
MAX_SETTLED_DRIFT = 0.01
"""Largest motion [m] of the tool relative to the palm over the last half second of the settle."""


def _hand_q(fingers: np.ndarray, thumb: np.ndarray) -> np.ndarray:
    return np.r_[np.tile(fingers, 3), thumb]


def sample_fist_grasp(name: str, rng: np.random.Generator | None) -> FistGrasp:
    """Tool ``name``'s :class:`FistGrasp` of ``TOOL_GRASPS`` with its yaw varied uniformly by up to
    ``GRASP_YAW_JITTER`` (one draw from ``rng``); the nominal grasp for ``rng=None``."""
    grasp = TOOL_GRASPS[name]
    if rng is None:
        return grasp
    return dataclasses.replace(grasp, yaw=grasp.yaw + float(rng.uniform(-GRASP_YAW_JITTER, GRASP_YAW_JITTER)))


def synthesized_tool_grasp(env, name: str, rng: np.random.Generator | None = None) -> None:
    """Settles tool ``name`` in a fist grasp with the arm at home (palm down), all by simulation.

    1. The arm is put at home and the hand in the open fist shape (``FIST_FINGER_OPEN``, thumb parked), at
       rest; the tool is placed at its :class:`FistGrasp` pose in the hand (with ``rng``, its yaw varied by
       :func:`sample_fist_grasp`: the episode's start varies with the seed), touching nothing, pinned by the
       scene's freezer (a helper holding it up while the hand closes).
    2. The index, middle and ring targets ramp to ``FIST_FINGER_CLOSED`` over 1/3 s and hold 1/6 s: the
       fingers close around the handle until their tips rest on the palm face.
    3. The tool is released (a free body from here on) and the hand holds its targets for 1 s: the tool drops
       into the fist and comes to rest. Hammer: its handle is pressed against the palm's ring-side edge
       (6.8 N) by the ring finger's distal phalanx (11.5 N), the index finger's base touching it on the other
       side of the centre of mass (0.5 N), caged by the fist; under :func:`hold_action` it then moves 0.4 mm
       and 0.011 rad relative to the palm in 1 s.

    The hand's PD targets stay at the fist: :func:`hold_action` gives the policy action that keeps them.
    Raises ValueError for a tool without a synthesized grasp and RuntimeError if the tool is not at rest in
    the hand at the end.
    """
    if name not in TOOL_GRASPS:
        raise ValueError(f"no synthesized grasp for '{name}' (have: {', '.join(TOOL_GRASPS)}); pass "
                         "options={'initial_state': ...} with a hand-off state from tool_grasp instead")
    grasp = sample_fist_grasp(name, rng)
    open_q, fist_q = _hand_q(FIST_FINGER_OPEN, FIST_THUMB), _hand_q(FIST_FINGER_CLOSED, FIST_THUMB)
    env.set_robot(np.asarray(env.scenario.robot.arm_home, dtype=float), open_q)
    palm = env.plant.GetBodyByName(PALM_BODY, env.hand)
    env.objects.set_pose(env.context, name, palm.EvalPoseInWorld(env.plant_context) @ grasp.X_PalmT(), frozen=True)
    harness = EnvHarness(env, wake=False)  # Touching the pinned tool must not release it early.
    RampTargets(harness, FIST_CLOSE_TICKS, hand=(open_q, fist_q))
    harness.step(FIST_HOLD_TICKS)
    frozen = env.objects.frozen_mask(env.context)
    frozen[env.objects.index(name)] = False
    env.objects.set_frozen(env.context, frozen)

    def X_PalmT() -> RigidTransform:
        return palm.EvalPoseInWorld(env.plant_context).InvertAndCompose(env.object_pose())

    harness.step(SETTLE_TICKS - SETTLE_TICKS // 2)
    before = X_PalmT()
    harness.step(SETTLE_TICKS // 2)
    drift = np.linalg.norm(X_PalmT().translation() - before.translation())
    if drift > MAX_SETTLED_DRIFT or env.object_position()[2] < TABLE_TOP + 0.1:
        raise RuntimeError(f"the synthesized grasp of {name} did not hold (moved {drift:.4f} m in the hand in "
                           f"0.5 s, centre of mass at z = {env.object_position()[2]:.3f} m)")


def hold_action(env) -> np.ndarray:
    """The policy action (19) that keeps the hand's current PD targets and the wrist where it is.

    Hand actions are absolute targets scaled to the joint limits, so the zero action is not "hold still" but
    the mid-range hand posture (fingers half open), which lets go of a fist-held tool.
    """
    return np.r_[unscale_limits_to_action(env._hand_target), np.zeros(3)]
