"""A block in a closed Allegro grasp stays in hand for 2 s while lifted (full station simulation).

The scripted tripod grasp of ``seqdex_drake.tasks.scripted.grasping``: the block stands upright on the box floor with
its 0.03 m side along world x; the arm (placed by inverse kinematics) lowers the open hand around it, the
thumb and the index + middle fingertips close on the two opposite faces with force-balanced PD targets, the
arm lifts 0.15 m in 1.5 s, and the hand holds for 2 s. Each case simulates 4.5 s (about 3 s of wall time).
"""

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw

from seqdex_drake import LoadScenario
from seqdex_drake.harness import MakeStationHarness
from seqdex_drake.robots.allegro import ALLEGRO_Q_MAX, ALLEGRO_Q_MIN, FINGERTIP_FRAMES, FINGERTIP_RADIUS, PALM_BODY
from seqdex_drake.tasks.scripted.grasping import (
    TRIPOD_DIGITS,
    ExecuteGrasp,
    MakeHandPlant,
    PlanTripodPickup,
    RampTargets,
    SolveTripodGrasp,
)

BLOCK_WIDTH = 0.03
"""The grasped side of every block type but the 2x2 (block_8) [m]."""
CONTACT_HEIGHT = 0.02
"""Height of the grasp centre above the block's bottom [m] (the body is 0.0375 m tall under the studs)."""
FLOOR = 0.6
LIFT = 0.15
HOLD_TICKS = 120


def test_tripod_grasp_shapes_touch_the_faces_within_limits():
    grasp = SolveTripodGrasp(BLOCK_WIDTH, spread=0.015, gap=0.02)
    plant = MakeHandPlant()
    context = plant.CreateDefaultContext()
    for q, gap in ((grasp.hand_q, 0.0), (grasp.pregrasp_q, 0.02)):
        assert np.all(q >= ALLEGRO_Q_MIN - 1e-9) and np.all(q <= ALLEGRO_Q_MAX + 1e-9)
        plant.SetPositions(context, q)
        tips = np.array([plant.GetFrameByName(FINGERTIP_FRAMES[d]).CalcPoseInWorld(context).translation()
                         for d in TRIPOD_DIGITS])
        np.testing.assert_allclose(tips, grasp.tip_targets(gap), atol=5e-4)
        # Index and middle on the far face, thumb on the near face, one sphere radius (+ gap) off each face.
        np.testing.assert_allclose(tips[:, 2] - grasp.p_PalmC[2],
                                   np.array([1, 1, -1]) * (BLOCK_WIDTH / 2 + FINGERTIP_RADIUS + gap), atol=5e-4)


def _block_contacts(harness, body):
    """(other body name, contact point in the palm frame) of every contact of ``body``."""
    plant = harness.objects.plant
    plant_context = plant.GetMyContextFromRoot(harness.context)
    X_PalmW = plant.GetBodyByName(PALM_BODY).EvalPoseInWorld(plant_context).inverse()
    results = harness.port("contact_results")
    contacts = []
    for k in range(results.num_point_pair_contacts()):
        info = results.point_pair_contact_info(k)
        if body.index() in (info.bodyA_index(), info.bodyB_index()):
            other = info.bodyB_index() if info.bodyA_index() == body.index() else info.bodyA_index()
            contacts.append((plant.get_body(other).name(), X_PalmW @ info.contact_point()))
    return contacts


@pytest.mark.parametrize("name, spread, scenario_text", [
    ("block_1", 0.015, "{}"),
    ("block_4", 0.015, "{}"),
    ("block_7", 0.0125, "{}"),  # 1x1: a 0.03 m face, so the two finger spheres nearly touch.
    ("block_1", 0.015, "{robot: {hand_kp: 20.0, hand_kd: 1.0}}"),  # The release's hand gains.
])
def test_block_stays_in_a_closed_grasp_while_lifted(name, spread, scenario_text):
    harness = MakeStationHarness(LoadScenario("building_blocks/grasp", scenario_text=scenario_text))
    plant = harness.objects.plant
    plant_context = plant.GetMyMutableContextFromRoot(harness.context)
    palm = plant.GetBodyByName(PALM_BODY)
    body = harness.objects.bodies[harness.objects.index(name)]
    # Upright on the box floor, short side along world x (the palm's z at the home orientation).
    X_WB = RigidTransform(RollPitchYaw(0.0, 0.0, np.pi / 2), [0.25, 0.19, FLOOR])
    harness.objects.set_pose(harness.context, name, X_WB)
    grasp = SolveTripodGrasp(BLOCK_WIDTH, spread=spread)
    plan = PlanTripodPickup(plant, plant_context, grasp, X_WB.translation() + [0.0, 0.0, CONTACT_HEIGHT],
                            palm.EvalPoseInWorld(plant_context).rotation(), force=1.0,
                            kp=harness.scenario.robot.hand_kp, lift=LIFT)

    def block_in_palm():
        return palm.EvalPoseInWorld(plant_context).inverse() @ body.EvalPoseInWorld(plant_context)

    ExecuteGrasp(harness, plan)
    X_PalmB_grasped = block_in_palm()
    fingers = {n for n, _ in _block_contacts(harness, body) if "link" in n}
    assert {"index_link_3", "middle_link_3", "thumb_link_3"} <= fingers, fingers
    RampTargets(harness, 90, arm=(plan.arm_grasp, plan.arm_lift))
    harness.step(10)
    X_PalmB_lifted = block_in_palm()
    z_lifted = body.EvalPoseInWorld(plant_context).translation()[2]
    harness.step(HOLD_TICKS)
    X_PalmB_held = block_in_palm()
    z_held = body.EvalPoseInWorld(plant_context).translation()[2]

    assert np.all(np.isfinite(plant.GetPositions(plant_context)))
    assert np.all(np.isfinite(plant.GetVelocities(plant_context)))
    assert z_lifted - FLOOR >= 0.10 and z_held - FLOOR >= 0.10, (z_lifted, z_held)
    lift_slip = np.linalg.norm(X_PalmB_lifted.translation() - X_PalmB_grasped.translation())
    hold_slip = np.linalg.norm(X_PalmB_held.translation() - X_PalmB_lifted.translation())
    hold_turn = X_PalmB_lifted.rotation().inverse().multiply(X_PalmB_held.rotation()).ToAngleAxis().angle()
    assert lift_slip < 0.01 and hold_slip < 0.01, (lift_slip, hold_slip)
    assert hold_turn < np.radians(10.0), np.degrees(hold_turn)
    # Held by the three grasping digits only (a distal phalanx may also rest on the block's top edge), each
    # touching it with its fingertip sphere.
    contacts = _block_contacts(harness, body)
    digits = {"index_link_3": 0, "middle_link_3": 1, "thumb_link_3": 3}
    assert {n for n, _ in contacts} == set(digits), contacts
    for other, digit in digits.items():
        p_PalmTip = plant.GetFrameByName(FINGERTIP_FRAMES[digit]).CalcPose(
            plant_context, palm.body_frame()).translation()
        gaps = [np.linalg.norm(p_PalmC - p_PalmTip) for n, p_PalmC in contacts if n == other]
        assert min(gaps) < FINGERTIP_RADIUS + 0.003, (other, gaps)
