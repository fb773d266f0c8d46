"""The chain's wrist IK (``WristTargetIntegrator``) holds the carry's turn latched at the handover: while the policy
is in charge a changing ``hold_rotation`` input (the carry's turn follows the block in hand) does not move the palm;
it follows it again once the approach is in charge."""

import numpy as np
from pydrake.math import RotationMatrix
from pydrake.systems.analysis import Simulator

from seqdex_drake import LoadScenario, MakeControllerPlant
from seqdex_drake.controller.chain_parts import WristTargetIntegrator
from seqdex_drake.robots.allegro import p_PalmHc_Palm
from seqdex_drake.robots.arm_ik import PalmIK

SCENARIO = "building_blocks/chain"


def angle(R_a: RotationMatrix, R_b: RotationMatrix) -> float:
    return (R_a.inverse() @ R_b).ToAngleAxis().angle()


def test_the_turn_is_latched_while_the_policy_is_in_charge_and_followed_otherwise():
    scenario = LoadScenario(SCENARIO)
    home = np.asarray(scenario.robot.arm_home, dtype=float)
    ik = PalmIK(MakeControllerPlant(scenario), p_PalmC_Palm=p_PalmHc_Palm)
    R_WP_hold = ik.palm_pose(home).rotation()
    wrist = WristTargetIntegrator(ik, R_WP_hold, scenario.control_period)
    simulator = Simulator(wrist)
    context = simulator.get_mutable_context()
    wrist.GetInputPort("franka.state").FixValue(context, np.r_[home, np.zeros(7)])
    wrist.GetInputPort("osc.desired_state").FixValue(context, np.r_[home, np.zeros(7)])
    wrist.GetInputPort("wrist_translation").FixValue(context, np.zeros(3))
    in_charge, turn = wrist.GetInputPort("policy_in_charge"), wrist.GetInputPort("hold_rotation")
    R_first, R_second = RotationMatrix.MakeZRotation(0.2), RotationMatrix.MakeXRotation(0.3)

    def run(policy: bool, R_turn: RotationMatrix, seconds: float) -> np.ndarray:
        in_charge.FixValue(context, [1.0 if policy else 0.0])
        turn.FixValue(context, R_turn.matrix().ravel())
        simulator.AdvanceTo(context.get_time() + seconds)
        return wrist.GetOutputPort("franka.desired_state").Eval(context)[:7]

    simulator.Initialize()
    assert angle(wrist.held_turn(context), RotationMatrix()) < 1e-12
    run(False, R_first, 0.1)  # The approach is in charge: the turn follows the input.
    assert angle(wrist.held_turn(context), R_first) < 1e-9
    q = run(True, R_second, 1.0)  # The policy took over; the input changed after.
    assert angle(wrist.held_turn(context), R_first) < 1e-9
    assert angle(ik.palm_pose(q).rotation(), R_first @ R_WP_hold) < 0.01  # The IK turned the palm to the latch ...
    assert angle(ik.palm_pose(q).rotation(), R_second @ R_WP_hold) > 0.3  # ... not to the input.
    run(False, R_second, 0.05)  # The approach again: the input is followed.
    assert angle(wrist.held_turn(context), R_second) < 1e-9
    simulator.Initialize()  # A restarted chain starts unturned.
    assert angle(wrist.held_turn(context), RotationMatrix()) < 1e-12
