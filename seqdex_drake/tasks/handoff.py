"""Scripted hand-offs: in-hand initial states for Insert and tool Reorient when no forward-initialization
buffer is given.

The paper's point (Sec. 4.1) is that random in-hand states are not physically stable, so Insert starts from
Grasp's successful terminal states (forward initialization, ``options={"initial_state": ...}``). Standalone,
an Insert reset instead *simulates* a scripted tripod pickup (``seqdex_drake.scene.grasping``): the block
stands on the table, the hand descends, squeezes with force-balanced targets and lifts it, a physically valid
grasp in about 140 control steps. Tool Reorient settles the hammer in a synthesized tripod grasp of its
handle (:func:`synthesized_tool_grasp`), about 60 control steps.
"""

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

from seqdex_drake.modeling.blocks import BLOCK_SPECS
from seqdex_drake.robots.allegro import PALM_BODY
from seqdex_drake.scene.grasping import (
    ExecuteGrasp,
    PlanTripodPickup,
    RampTargets,
    SolveTripodGrasp,
    SqueezeTargets,
)

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
        arm = self.env._arm_target if arm_q is None else np.asarray(arm_q, dtype=float)
        hand = self.env._hand_target if hand_q is None else np.asarray(hand_q, dtype=float)
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


#: In-hand tripod grasps synthesized for Tool Reorient: (grasp point in the tool frame, handle width, force).
TOOL_GRASPS = {"hammer": (np.array([0.0, 0.12, -0.0115]), 0.0175, 1.0)}


def synthesized_tool_grasp(env, name: str) -> None:
    """Settles tool ``name`` in a tripod grasp with the arm at home: the hand takes the contact shape, the tool
    is placed at rest between the tips, force-balanced squeeze targets ramp up over 1/3 s and it settles for
    2/3 s. Raises RuntimeError if it is not held."""
    if name not in TOOL_GRASPS:
        raise ValueError(f"no synthesized grasp for '{name}' (have: {', '.join(TOOL_GRASPS)}); pass "
                         "options={'initial_state': ...} with a hand-off state from tool_grasp instead")
    p_TC, width, force = TOOL_GRASPS[name]
    grasp = SolveTripodGrasp(width, spread=0.0125)
    env.set_robot(np.asarray(env.scenario.robot.arm_home, dtype=float), grasp.hand_q)
    X_WPalm = env.plant.GetBodyByName(PALM_BODY, env.hand).EvalPoseInWorld(env.plant_context)
    x_T = X_WPalm.rotation().matrix()[:, 2]  # The gripped faces' normal: the palm's z.
    y_T = np.array([0.0, 1.0, 0.0]) - x_T[1] * x_T
    y_T /= np.linalg.norm(y_T)
    R_WT = RotationMatrix(np.column_stack([x_T, y_T, np.cross(x_T, y_T)]))
    X_WT = RigidTransform(R_WT, X_WPalm @ grasp.p_PalmC - R_WT.matrix() @ p_TC)
    # Placed at rest between the tips of the contact shape, free: the squeeze ramps up while it settles (a
    # tool released from a pin into an established squeeze is shot out by the residual imbalance).
    env.objects.set_pose(env.context, name, X_WT, frozen=False)
    harness = EnvHarness(env)
    squeeze = SqueezeTargets(env.plant, env.plant_context, grasp, force, env.scenario.robot.hand_kp)
    RampTargets(harness, 20, hand=(grasp.hand_q, squeeze))
    harness.step(40)
    moved = np.linalg.norm(env.object_pose().translation() - X_WT.translation())
    if moved > 0.03:
        raise RuntimeError(f"the synthesized grasp of {name} did not hold (moved {moved:.3f} m)")
