"""The operational-space approach controller: reaching, limits, handover, program reuse and failure handling.

The reaching test closes the loop around the real station (Franka + Allegro, discrete plant at 2 ms, the
controller at 60 Hz) and reuses one Simulator across targets, resetting the arm between them.
"""

import logging

import numpy as np
import pytest
from pydrake.math import RotationMatrix
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from seqdex_drake import LoadScenario, MakeControllerPlant, MakeStation
from seqdex_drake.control.osc import AddOperationalSpaceController, OperationalSpaceController, OscParams
from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q
from seqdex_drake.robots.franka import FRANKA_EFFORT_MAX, FRANKA_Q_MAX, FRANKA_Q_MIN, FRANKA_V_MAX
from seqdex_drake.scene.objects import SceneObjects

SCENARIO = "building_blocks/grasp"
MAX_TILT_DEG = 15.0
"""Largest deviation (deg) of the palm from its held orientation during an approach."""
MAX_DIP = 0.02
"""Largest overshoot (m) of the controlled point below the hover point."""


class Rig:
    """Station + OSC + constant target and hand hold, one Simulator reused across targets."""

    def __init__(self):
        self.scenario = scenario = LoadScenario(SCENARIO)
        builder = DiagramBuilder()
        self.station = builder.AddNamedSystem("station", MakeStation(scenario))
        self.osc = AddOperationalSpaceController(builder, self.station, scenario)
        self.target = builder.AddNamedSystem("target", ConstantVectorSource(np.zeros(3)))
        builder.Connect(self.target.get_output_port(), self.osc.GetInputPort("target_position"))
        hand = builder.AddNamedSystem("hand_hold", ConstantVectorSource(np.r_[ALLEGRO_OPEN_Q, np.zeros(16)]))
        builder.Connect(hand.get_output_port(), self.station.GetInputPort("allegro.desired_state"))
        self.diagram = builder.Build()
        self.simulator = Simulator(self.diagram)
        ApplySimulatorConfig(scenario.simulator_config, self.simulator)
        self.context = self.simulator.get_mutable_context()
        SceneObjects(self.station, scenario).park(self.context)  # Objects frozen off the table.
        self.plant = self.station.GetSubsystemByName("plant")
        self.home = np.asarray(scenario.robot.arm_home, dtype=float)
        self.gravity_plant = MakeControllerPlant(scenario)  # Independent gravity model for the torque check.
        self.gravity_context = self.gravity_plant.CreateDefaultContext()

    def reset(self, p_WT: np.ndarray) -> None:
        """Arm at home at rest, time zero, new target; re-initializes the controller."""
        self.context.SetTime(0.0)
        plant_context = self.plant.GetMyMutableContextFromRoot(self.context)
        franka = self.plant.GetModelInstanceByName("franka")
        self.plant.SetPositions(plant_context, franka, self.home)
        self.plant.SetVelocities(plant_context, franka, np.zeros(7))
        self.set_target(p_WT)
        self.simulator.Initialize()

    def set_target(self, p_WT: np.ndarray) -> None:
        self.target.get_mutable_source_value(self.target.GetMyMutableContextFromRoot(self.context)).SetFromVector(
            p_WT)

    def arm_state(self) -> np.ndarray:
        return self.station.GetOutputPort("franka.state").Eval(self.station.GetMyContextFromRoot(self.context))

    def osc_output(self, name: str) -> np.ndarray:
        return self.osc.GetOutputPort(name).Eval(self.osc.GetMyContextFromRoot(self.context))

    def num_contacts(self) -> int:
        results = self.station.GetOutputPort("contact_results").Eval(self.station.GetMyContextFromRoot(self.context))
        return results.num_point_pair_contacts()

    def pd_torque(self, command: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Torque the station's joint PD actuators exert for ``command`` at state ``x`` (gravity fed forward)."""
        robot = self.scenario.robot
        self.gravity_plant.SetPositions(self.gravity_context, x[:7])
        tau_g = self.gravity_plant.CalcGravityGeneralizedForces(self.gravity_context)
        return robot.arm_kp * (command[:7] - x[:7]) + robot.arm_kd * (command[7:] - x[7:]) - tau_g

    def tilt(self, q: np.ndarray) -> float:
        """Angle (rad) between the palm orientation at ``q`` and the controller's held orientation."""
        plant = self.gravity_plant
        plant.SetPositions(self.gravity_context, q)
        R_WPalm = plant.EvalBodyPoseInWorld(self.gravity_context, plant.GetBodyByName("palm")).rotation()
        return R_WPalm.InvertAndCompose(self.osc.R_WD).ToAngleAxis().angle()

    def run(self, p_WT: np.ndarray, duration: float = 2.0) -> dict:
        """Runs one approach, checking limits at every control tick; returns a summary."""
        self.reset(p_WT)
        dt = self.scenario.control_period
        p_WH = self.osc.hover_point(p_WT)
        summary = dict(first_within_1cm=None, handover_time=None, handover_error=None, max_torque_ratio=0.0,
                       max_velocity_ratio=0.0, min_limit_margin=np.inf, contacts=0, max_tilt=0.0, max_dip=-np.inf,
                       active=[])
        for k in range(1, round(duration / dt) + 1):
            # Just past tick k, so that tick k's events have run: the plant step due then (every third tick meets
            # one; the plant's sampled outputs make it an unrestricted update, which runs first), then the OSC
            # update, which read the state x we read now and computed the command we read now.
            self.simulator.AdvanceTo(k * dt + 1e-9)
            x = self.arm_state().copy()
            command = self.osc_output("franka.desired_state")
            summary["max_torque_ratio"] = max(summary["max_torque_ratio"],
                                              np.max(np.abs(self.pd_torque(command, x)) / FRANKA_EFFORT_MAX))
            summary["max_velocity_ratio"] = max(summary["max_velocity_ratio"],
                                                np.max(np.abs(x[7:]) / FRANKA_V_MAX))
            summary["min_limit_margin"] = min(summary["min_limit_margin"],
                                              np.min(np.r_[x[:7] - FRANKA_Q_MIN, FRANKA_Q_MAX - x[:7]]))
            summary["contacts"] = max(summary["contacts"], self.num_contacts())
            p_WC = self.osc.controlled_point(x[:7])
            error = np.linalg.norm(p_WC - p_WH)
            summary["max_dip"] = max(summary["max_dip"], p_WH[2] - p_WC[2])
            summary["max_tilt"] = max(summary["max_tilt"], self.tilt(x[:7]))
            if error < 0.01 and summary["first_within_1cm"] is None:
                summary["first_within_1cm"] = k * dt
            active = self.osc_output("approach_active")[0]
            summary["active"].append(active)
            if active == 0.0 and summary["handover_time"] is None:
                summary["handover_time"] = k * dt
                summary["handover_error"] = error
                summary["handover_target_distance"] = np.linalg.norm(p_WC - p_WT)
        summary["final_error"] = error
        summary["final_tilt"] = self.tilt(x[:7])
        summary["qp_failures"] = self.osc_output("qp_failures")[0]
        return summary


@pytest.fixture(scope="module")
def rig():
    return Rig()


def _random_targets(count: int, seed: int) -> np.ndarray:
    """Targets T whose hover points lie over the work cell (z 0.80-0.95 m, above the box walls) or, for a
    quarter of them, inside the box away from its walls (z 0.70-0.80 m)."""
    rng = np.random.default_rng(seed)
    above = rng.uniform([0.05, -0.20, 0.80], [0.40, 0.30, 0.95], size=(count - count // 4, 3))
    inside = rng.uniform([0.08, 0.06, 0.70], [0.28, 0.26, 0.80], size=(count // 4, 3))
    return np.vstack([above, inside]) - [0.0, 0.0, OscParams().hover_height]


def test_reaches_20_random_targets_within_2s_and_limits(rig):
    params = rig.osc.params
    for p_WT in _random_targets(20, seed=7):
        s = rig.run(p_WT)
        where = f"target {np.round(p_WT, 3)}: {s}"
        assert s["first_within_1cm"] is not None and s["final_error"] < 0.01, where
        assert s["max_torque_ratio"] <= 1.0, where
        assert s["max_velocity_ratio"] <= 1.0, where
        assert s["min_limit_margin"] > 0.0, where
        assert s["contacts"] == 0 and s["qp_failures"] == 0, where
        # Handover: active until the hand is at the hover point or within handover distance of the target.
        assert s["active"][0] == 1.0 and s["active"][-1] == 0.0, where
        assert (s["handover_error"] <= params.hover_tolerance + 1e-9
                or s["handover_target_distance"] <= params.handover_distance + 1e-9), where
        assert s["final_tilt"] < np.radians(2.0) and s["max_tilt"] < np.radians(MAX_TILT_DEG), where
        assert s["max_dip"] < MAX_DIP, where  # Never closer than 3 cm above the target.


def test_unreachable_target_saturates_within_limits(rig):
    s = rig.run(np.array([1.2, 0.0, 0.7]), duration=1.5)
    assert s["max_torque_ratio"] <= 1.0 and s["max_velocity_ratio"] <= 1.0 and s["min_limit_margin"] > 0.0, s
    assert s["qp_failures"] == 0 and all(a == 1.0 for a in s["active"]), s


# ------------------------------------------------------------------------------ the controller on its own
def _standalone(params: OscParams | None = None):
    """The controller alone, inputs fixed (arm held at home), stepped by its own Simulator."""
    scenario = LoadScenario(SCENARIO)
    osc = OperationalSpaceController(MakeControllerPlant(scenario), scenario.control_period,
                                     scenario.robot.arm_kp, scenario.robot.arm_kd, params,
                                     home_q=np.asarray(scenario.robot.arm_home))
    simulator = Simulator(osc)
    context = simulator.get_mutable_context()
    osc.GetInputPort("franka.state").FixValue(context, np.r_[scenario.robot.arm_home, np.zeros(7)])
    return osc, simulator, context


def test_program_is_built_once_and_reused():
    osc, simulator, context = _standalone()
    prog = osc.program
    counts = (prog.num_vars(), len(prog.GetAllCosts()), len(prog.GetAllConstraints()))
    osc.GetInputPort("target_position").FixValue(context, [0.3, 0.1, 0.75])
    simulator.Initialize()
    simulator.AdvanceTo(100 / 60)  # Ticks at 0, 1/60, ..., 99/60 (events at the end time wait).
    assert osc.statistics.ticks == 100 and osc.statistics.failures == 0
    assert osc.program is prog
    assert (prog.num_vars(), len(prog.GetAllCosts()), len(prog.GetAllConstraints())) == counts
    # The arm is held (input fixed), so every tick commands motion toward the far hover point.
    assert np.any(np.abs(osc.GetOutputPort("franka.desired_state").Eval(context)[7:]) > 1e-3)


def test_handover_hysteresis():
    osc, simulator, context = _standalone()
    p_WC = osc.controlled_point(np.asarray(LoadScenario(SCENARIO).robot.arm_home))
    target = osc.GetInputPort("target_position")
    target.FixValue(context, p_WC - [0.0, 0.0, 0.05 + 0.005])  # Hover point 5 mm below the hand.
    simulator.Initialize()
    simulator.AdvanceTo(0.02)
    assert osc.GetOutputPort("approach_active").Eval(context)[0] == 0.0
    target.FixValue(context, p_WC - [0.0, 0.0, 0.09])  # 9 cm away: inside the re-engage distance.
    simulator.AdvanceTo(0.04)
    assert osc.GetOutputPort("approach_active").Eval(context)[0] == 0.0
    target.FixValue(context, p_WC - [0.0, 0.0, 0.15])  # A new target 15 cm away: the approach restarts.
    simulator.AdvanceTo(0.06)
    assert osc.GetOutputPort("approach_active").Eval(context)[0] == 1.0


def test_a_new_stage_epoch_restarts_the_approach():
    osc, simulator, context = _standalone()
    p_WC = osc.controlled_point(np.asarray(LoadScenario(SCENARIO).robot.arm_home))
    osc.GetInputPort("target_position").FixValue(context, p_WC - [0.0, 0.0, 0.05 + 0.005])
    epoch = osc.GetInputPort("stage_epoch")
    epoch.FixValue(context, [0.0])
    simulator.Initialize()
    simulator.AdvanceTo(0.02)
    assert osc.GetOutputPort("approach_active").Eval(context)[0] == 0.0
    # 9 cm away: inside the re-engage distance, so only a new epoch (a restarted stage) re-arms the approach.
    osc.GetInputPort("target_position").FixValue(context, p_WC - [0.0, 0.0, 0.09])
    simulator.AdvanceTo(0.04)
    assert osc.GetOutputPort("approach_active").Eval(context)[0] == 0.0
    epoch.FixValue(context, [1.0])
    simulator.AdvanceTo(0.06)
    assert osc.GetOutputPort("approach_active").Eval(context)[0] == 1.0


def test_an_approach_that_cannot_arrive_hands_over_after_its_timeout():
    """The arm is held (input fixed), so the hover point 20 cm away is never reached: without a timeout the approach
    stays active; with one it hands over after that long, from the start and after a new stage epoch alike."""
    osc, simulator, context = _standalone(OscParams(approach_timeout=0.2, reengage_distance=float("inf")))
    p_WC = osc.controlled_point(np.asarray(LoadScenario(SCENARIO).robot.arm_home))
    osc.GetInputPort("target_position").FixValue(context, p_WC - [0.0, 0.0, 0.25])
    epoch = osc.GetInputPort("stage_epoch")
    epoch.FixValue(context, [0.0])
    simulator.Initialize()
    active = osc.GetOutputPort("approach_active")
    simulator.AdvanceTo(0.18)
    assert active.Eval(context)[0] == 1.0
    simulator.AdvanceTo(0.26)
    assert active.Eval(context)[0] == 0.0
    epoch.FixValue(context, [1.0])
    simulator.AdvanceTo(0.3)
    assert active.Eval(context)[0] == 1.0  # Re-armed, with a fresh timeout ...
    simulator.AdvanceTo(0.45)
    assert active.Eval(context)[0] == 1.0
    simulator.AdvanceTo(0.55)
    assert active.Eval(context)[0] == 0.0  # ... that runs out 0.2 s after the new epoch.
    osc, simulator, context = _standalone()
    osc.GetInputPort("target_position").FixValue(context, p_WC - [0.0, 0.0, 0.25])
    simulator.Initialize()
    simulator.AdvanceTo(1.0)
    assert osc.GetOutputPort("approach_active").Eval(context)[0] == 1.0  # The default: no timeout.


def test_a_settle_condition_holds_the_handover_until_the_hand_is_turned_and_slow():
    """With ``handover_angle`` the approach hands over at the hover point only once the hand holds its orientation
    (a carry's turn, the ``hold_rotation`` input, included); with ``handover_speed`` only once the hand is slow. The
    arm is held at home (input fixed), so a turn of 0.2 rad is never made and a moving state is never slowed."""
    home = np.asarray(LoadScenario(SCENARIO).robot.arm_home)
    for params, turn, velocity, expected in [
            (OscParams(), 0.2, np.zeros(7), 0.0),  # Position alone: hands over.
            (OscParams(handover_angle=0.05), 0.0, np.zeros(7), 0.0),  # Turned as held: hands over.
            (OscParams(handover_angle=0.05), 0.2, np.zeros(7), 1.0),  # 0.2 rad from the held turn: waits.
            (OscParams(handover_speed=0.02), 0.0, np.full(7, 0.3), 1.0),  # Moving: waits.
            (OscParams(handover_speed=0.02), 0.0, np.zeros(7), 0.0)]:  # At rest: hands over.
        osc, simulator, context = _standalone(params)
        osc.GetInputPort("franka.state").FixValue(context, np.r_[home, velocity])
        p_WC = osc.controlled_point(home)
        osc.GetInputPort("target_position").FixValue(context, p_WC - [0.0, 0.0, 0.05 + 0.005])
        osc.GetInputPort("hold_rotation").FixValue(context, RotationMatrix.MakeZRotation(turn).matrix().ravel())
        simulator.Initialize()
        simulator.AdvanceTo(0.05)
        assert osc.GetOutputPort("approach_active").Eval(context)[0] == expected, (params, turn, velocity)


def test_nan_target_raises_clear_error():
    osc, simulator, context = _standalone()
    osc.GetInputPort("target_position").FixValue(context, [0.3, np.nan, 0.75])
    with pytest.raises(ValueError, match="non-finite target_position"):
        simulator.Initialize()
        simulator.AdvanceTo(0.05)


def test_failed_qp_holds_last_command_and_counts(caplog):
    # Torque limits at 1 % of the effort cannot even hold the arm against gravity: the QP is infeasible.
    osc, simulator, context = _standalone(OscParams(effort_scale=0.01))
    osc.GetInputPort("target_position").FixValue(context, [0.3, 0.1, 0.75])
    with caplog.at_level(logging.WARNING, logger="seqdex_drake.control.osc"):
        simulator.Initialize()
        held = osc.GetOutputPort("franka.desired_state").Eval(context).copy()
        simulator.AdvanceTo(5 / 60)
    assert osc.GetOutputPort("qp_failures").Eval(context)[0] == 5  # Ticks at 0, ..., 4/60.
    np.testing.assert_array_equal(osc.GetOutputPort("franka.desired_state").Eval(context), held)
    assert sum("OSC QP not solved" in r.getMessage() for r in caplog.records) == 1


def test_travel_height_rises_first_crosses_then_descends():
    straight, _, _ = _standalone()
    osc, _, _ = _standalone(OscParams(travel_height=0.9, travel_xy=0.05))
    p_WH = np.array([0.25, 0.19, 0.72])  # A hover point over the box.
    low_outside = np.array([0.25, -0.2, 0.70])  # Over the baseplate, below the box walls' tops.
    np.testing.assert_array_equal(straight.waypoint(low_outside, p_WH), p_WH)  # Default: a straight line.
    np.testing.assert_allclose(osc.waypoint(low_outside, p_WH), [0.25, -0.2, 0.9])  # Up in place first,
    np.testing.assert_allclose(osc.waypoint(np.array([0.25, -0.2, 0.895]), p_WH), [0.25, 0.19, 0.9])  # across,
    np.testing.assert_allclose(osc.waypoint(np.array([0.25, 0.16, 0.9]), p_WH), p_WH)  # then down within 5 cm.
    high = np.array([0.25, 0.19, 1.0])  # A hover point above the travel height: crossing at its height.
    np.testing.assert_allclose(osc.waypoint(np.array([0.25, -0.2, 1.0]), high), high)
