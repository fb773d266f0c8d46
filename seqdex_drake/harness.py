"""A station with settable joint targets, its Simulator and its object manager, stepped at the control rate.

The smallest closed loop around :func:`~seqdex_drake.station.MakeStation`: constant desired states for the
Franka and Allegro PD controllers (changed between steps with :meth:`StationHarness.set_targets`), object
placement and freezing through :class:`~seqdex_drake.scene.objects.SceneObjects`. Scripts, tests and
benchmarks use it; the environments of the sub-tasks build their own diagrams around the same station.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator
from pydrake.systems.framework import Context, Diagram, DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q
from seqdex_drake.scenario import Scenario, ScenarioError
from seqdex_drake.scene.objects import SceneObjects
from seqdex_drake.scene.piles import LoadPiles
from seqdex_drake.station import MODELS_DIR, MODELS_PACKAGE, MakeStation, RefreshSampledOutputs


@dataclasses.dataclass
class StationHarness:
    """The pieces of a simulated station; build it with :func:`MakeStationHarness`."""

    scenario: Scenario
    diagram: Diagram
    station: Diagram
    simulator: Simulator
    objects: SceneObjects
    arm_target: ConstantVectorSource
    hand_target: ConstantVectorSource

    @property
    def context(self) -> Context:
        return self.simulator.get_mutable_context()

    def set_targets(self, arm_q: np.ndarray | None = None, hand_q: np.ndarray | None = None) -> None:
        """Sets the PD position targets (zero target velocity) of the arm and/or the hand."""
        for source, q in ((self.arm_target, arm_q), (self.hand_target, hand_q)):
            if q is not None:
                value = source.get_mutable_source_value(source.GetMyMutableContextFromRoot(self.context))
                value.SetFromVector(np.concatenate([q, np.zeros(len(q))]))

    def step(self, n: int = 1, wake: bool = True) -> None:
        """Advances ``n`` control periods, letting the hand wake frozen objects after each."""
        for _ in range(n):
            self.simulator.AdvanceTo(self.context.get_time() + self.scenario.control_period)
            if wake:
                self.objects.update(self.context)

    def port(self, name: str):
        """Evaluates the station output port ``name``."""
        return self.station.GetOutputPort(name).Eval(self.station.GetMyContextFromRoot(self.context))

    def restore_pile(self, index: int) -> None:
        """Restores cached pile ``index`` (modulo the number cached) and freezes blocks far from the palm."""
        piles = LoadPiles(ResolvePackageUrl(self.scenario.pile_file), self.objects.names)
        self.objects.set_positions(self.context, piles[index % len(piles)],
                                   frozen=np.zeros(len(self.objects.names), dtype=bool))
        if self.scenario.freeze.enabled:
            self.objects.freeze_far_from(self.context, self.objects.hand_points(self.context)[-1])


def ResolvePackageUrl(url: str) -> str:
    """Resolves ``package://seqdex_models/...`` (or a plain path) to a filesystem path."""
    prefix = f"package://{MODELS_PACKAGE}/"
    return str(MODELS_DIR / url[len(prefix):]) if url.startswith(prefix) else url


def MakeStationHarness(scenario: Scenario, meshcat=None, arm_q=None, hand_q=None,
                       pile_index: int | None = None) -> StationHarness:
    """Builds the station, holds the robot at ``arm_q``/``hand_q`` (default: home, open) and lays out objects.

    Objects start per ``scenario.object_layout``: ``pile`` restores cached pile ``pile_index`` (default:
    the scenario's random seed), ``parked`` parks every object, frozen, off the table.
    """
    builder = DiagramBuilder()
    station = builder.AddNamedSystem("station", MakeStation(scenario, meshcat=meshcat))
    arm_q = np.asarray(scenario.robot.arm_home if arm_q is None else arm_q, dtype=float)
    hand_q = np.asarray(ALLEGRO_OPEN_Q if hand_q is None else hand_q, dtype=float)
    arm_target = builder.AddNamedSystem("franka.target", ConstantVectorSource(np.r_[arm_q, np.zeros(7)]))
    hand_target = builder.AddNamedSystem("allegro.target", ConstantVectorSource(np.r_[hand_q, np.zeros(16)]))
    builder.Connect(arm_target.get_output_port(), station.GetInputPort("franka.desired_state"))
    builder.Connect(hand_target.get_output_port(), station.GetInputPort("allegro.desired_state"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    ApplySimulatorConfig(scenario.simulator_config, simulator)
    objects = SceneObjects(station, scenario)
    harness = StationHarness(scenario, diagram, station, simulator, objects, arm_target, hand_target)
    plant = station.GetSubsystemByName("plant")
    plant_context = plant.GetMyMutableContextFromRoot(harness.context)
    plant.SetPositions(plant_context, plant.GetModelInstanceByName("franka"), arm_q)
    plant.SetPositions(plant_context, plant.GetModelInstanceByName("allegro"), hand_q)
    if objects.names:
        if scenario.object_layout == "pile":
            harness.restore_pile(scenario.random_seed if pile_index is None else pile_index)
        elif scenario.object_layout == "parked":
            objects.park(harness.context)
        else:
            raise ScenarioError(f"unknown object_layout '{scenario.object_layout}'")
    simulator.Initialize()
    RefreshSampledOutputs(plant, plant_context)  # Motor torques and contacts of the start state.
    return harness
