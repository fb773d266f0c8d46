"""Scripted hand-offs: an in-hand initial state for Insert when no forward-initialization buffer is given.

The paper's point (Sec. 4.1) is that random in-hand states are not physically stable, so Insert starts from
Grasp's successful terminal states (forward initialization, ``options={"initial_state": ...}``). Standalone,
an Insert reset instead *simulates* a scripted tripod pickup (``seqdex_drake.scene.grasping``): the block
stands on the table, the hand descends, squeezes with force-balanced targets and lifts it, a physically valid
grasp in about 140 control steps.
"""

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw

from seqdex_drake.modeling.blocks import BLOCK_SPECS
from seqdex_drake.robots.allegro import PALM_BODY
from seqdex_drake.scene.grasping import ExecuteGrasp, PlanTripodPickup, RampTargets, SolveTripodGrasp

#: Where Insert's scripted pickup takes the block from: the free table area beside the baseplate.
PICKUP_XY = np.array([0.22, 0.12])
TABLE_TOP = 0.6
CONTACT_HEIGHT = 0.02
GRASP_FORCE = 1.0


class EnvHarness:
    """The part of :class:`~seqdex_drake.harness.StationHarness` the scripted grasp uses, over an environment."""

    def __init__(self, env):
        self.env = env
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
            self.objects.update(self.context)


def scripted_pickup(env, name: str, yaw_jitter: float, rng: np.random.Generator, lift: float = 0.12) -> None:
    """Puts block ``name`` upright on the table and runs a scripted tripod pickup, ending with it lifted.

    The block's 0.03 m sides face the palm's z (world x at the home orientation), turned by up to
    ``yaw_jitter`` rad; raises RuntimeError if the block was not picked up.
    """
    block_type = int(name.split("_")[1])
    width = BLOCK_SPECS[block_type].footprint[1]
    X_WB = RigidTransform(RollPitchYaw(0.0, 0.0, np.pi / 2 + rng.uniform(-yaw_jitter, yaw_jitter)),
                          [*PICKUP_XY, TABLE_TOP + 0.0005])
    env.objects.set_pose(env.context, name, X_WB, frozen=False)
    harness = EnvHarness(env)
    plant, plant_context = env.plant, env.plant_context
    palm = plant.GetBodyByName(PALM_BODY, env.hand)
    env.set_robot(env.hover_arm(X_WB.translation()), env.hand_q())
    grasp = SolveTripodGrasp(width, spread=0.015 if width >= 0.03 else 0.0125)
    plan = PlanTripodPickup(plant, plant_context, grasp, X_WB.translation() + [0.0, 0.0, CONTACT_HEIGHT],
                            palm.EvalPoseInWorld(plant_context).rotation(), force=GRASP_FORCE,
                            kp=env.scenario.robot.hand_kp, lift=lift)
    ExecuteGrasp(harness, plan)
    RampTargets(harness, 60, arm=(plan.arm_grasp, plan.arm_lift))
    harness.step(10)
    if env.object_position()[2] < X_WB.translation()[2] + 0.5 * lift:
        raise RuntimeError(f"the scripted pickup of {name} failed; pass a hand-off buffer state instead")
