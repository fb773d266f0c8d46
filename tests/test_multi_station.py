"""Several stations and chain controllers in one diagram: ``name=`` makes their subsystem names unique and
prefixes their Meshcat paths; docs/architecture.md's example runs; a chain without a target says to call
SetChainTarget.

Every diagram's subsystem names are checked before ``Build()``: Drake aborts the process on duplicates."""

import re
from pathlib import Path

import numpy as np
import pytest
from pydrake.geometry import Meshcat, MeshcatParams
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from seqdex_drake import (
    ChainParams,
    ConnectChainController,
    LoadScenario,
    MakeChainController,
    MakeStation,
    SetChainTarget,
)
from seqdex_drake.scene.objects import SceneObjects
from seqdex_drake.tasks.blocks_common import resting_pose
from seqdex_drake.tasks.handover_common import TABLE_TOP

ARCHITECTURE = Path(__file__).resolve().parents[1] / "docs" / "architecture.md"
STAGES = [("reach", None), ("lower", None)]
PARAMS = ChainParams(untrained_hidden_sizes=(16,))


def _loopback_meshcat() -> Meshcat:
    """A Meshcat on an ephemeral loopback port: no clash with other Meshcats on this machine, and no listener on
    every interface (Drake's default host) left in the test process (tests/test_ray_vector.py checks them)."""
    return Meshcat(MeshcatParams(host="localhost", port=0))


@pytest.fixture
def meshcat():
    return _loopback_meshcat()


@pytest.fixture(scope="module")
def scenario():
    return LoadScenario("handover/reach", scenario_text="{visualization: {publish_contacts: true}}")


def build(builder: DiagramBuilder) -> Simulator:
    names = [builder.GetSystems()[i].get_name() for i in range(len(builder.GetSystems()))]
    assert len(set(names)) == len(names), f"duplicate subsystem names {names} would abort Build()"
    return Simulator(builder.Build())


def place(station, chain, scenario, context, y: float) -> np.ndarray:
    """Puts block_1 on the table at (0.37, y), makes it the chain's target; returns its centre of mass."""
    SceneObjects(station, scenario).set_pose(context, "block_1", resting_pose(1, 0.0, 0.0, 0.0, [0.37, y], TABLE_TOP))
    plant = station.GetSubsystemByName("plant")
    body = plant.GetBodyByName("block", plant.GetModelInstanceByName("block_1"))
    SetChainTarget(chain, context, int(body.index()))
    return plant.EvalBodyPoseInWorld(plant.GetMyContextFromRoot(context), body) @ body.default_com()


def test_two_stations_and_two_chain_controllers_share_one_meshcat(meshcat, scenario):
    builder = DiagramBuilder()
    cells = {}
    for side in ("left", "right"):
        station = builder.AddSystem(MakeStation(scenario, meshcat=meshcat, name=side))
        chain = builder.AddSystem(MakeChainController(scenario, STAGES, params=PARAMS, meshcat=meshcat,
                                                      name=f"{side}_chain"))
        assert (station.get_name(), chain.get_name()) == (side, f"{side}_chain")
        ConnectChainController(builder, station, chain)
        cells[side] = station, chain
    simulator = build(builder)
    context = simulator.get_mutable_context()
    blocks = {side: place(*cells[side], scenario, context, y) for side, y in (("left", 0.03), ("right", 0.13))}
    simulator.AdvanceTo(0.1)  # 6 control ticks.

    for side, (station, chain) in cells.items():  # Each controller reads its own station.
        target = chain.GetOutputPort("approach_target").Eval(chain.GetMyContextFromRoot(context))
        np.testing.assert_allclose(target, blocks[side], atol=1e-3)
        arm = station.GetOutputPort("franka.state").Eval(station.GetMyContextFromRoot(context))
        assert np.all(np.isfinite(arm))
    for side in ("left", "right"):
        for path in ("illustration", "illustration/franka", "illustration/block_1", "proximity", "contact_forces"):
            assert meshcat.HasPath(f"/drake/{side}/{path}"), path
        assert meshcat.HasPath(f"/drake/{side}_chain/chain/target")
    for path in ("illustration", "proximity", "contact_forces", "chain/target"):  # Nobody draws unprefixed.
        assert not meshcat.HasPath(f"/drake/{path}"), path


def test_default_names_and_meshcat_paths_are_unchanged(meshcat, scenario):
    builder = DiagramBuilder()
    station = builder.AddSystem(MakeStation(scenario, meshcat=meshcat))
    chain = builder.AddSystem(MakeChainController(scenario, STAGES, params=PARAMS, meshcat=meshcat))
    assert (station.get_name(), chain.get_name()) == ("station_handover_reach", "chain_controller")
    ConnectChainController(builder, station, chain)
    simulator = build(builder)
    place(station, chain, scenario, simulator.get_mutable_context(), 0.08)
    simulator.AdvanceTo(0.05)
    for path in ("illustration/franka", "proximity", "contact_forces", "chain/target"):
        assert meshcat.HasPath(f"/drake/{path}"), path


@pytest.mark.parametrize("name", ["", "a/b", "a::b"])
def test_names_that_cannot_name_a_system_or_a_meshcat_path_are_refused(scenario, name):
    with pytest.raises(ValueError, match="name must be a non-empty string"):
        MakeStation(scenario, name=name)
    with pytest.raises(ValueError, match="name must be a non-empty string"):
        MakeChainController(scenario, STAGES, params=PARAMS, name=name)


def test_a_chain_without_a_target_says_to_call_set_chain_target(scenario):
    builder = DiagramBuilder()
    station = builder.AddNamedSystem("station", MakeStation(scenario))
    chain = builder.AddNamedSystem("chain", MakeChainController(scenario, STAGES, params=PARAMS))
    ConnectChainController(builder, station, chain)
    simulator = build(builder)
    assembler = chain.GetSubsystemByName("observation.base")
    with pytest.raises(RuntimeError, match=r"SetChainTarget\(controller, root_context"):
        assembler.GetOutputPort("observation").Eval(assembler.GetMyContextFromRoot(simulator.get_context()))
    with pytest.raises(RuntimeError, match=r"SetChainTarget\("):
        simulator.AdvanceTo(0.05)


def test_the_architecture_doc_example_runs(capsys, monkeypatch):
    import pydrake.geometry

    monkeypatch.setattr(pydrake.geometry, "StartMeshcat", _loopback_meshcat)
    blocks = re.findall(r"```python\n(.*?)```", ARCHITECTURE.read_text(), flags=re.DOTALL)
    code = [block for block in blocks if "MakeStation(scenario, meshcat=meshcat, name=side)" in block]
    assert len(code) == 1, "docs/architecture.md's 'Several stations in one diagram' example is missing"
    assert "simulator.AdvanceTo(1.0)" in code[0]
    namespace = {}
    exec(compile(code[0].replace("simulator.AdvanceTo(1.0)", "simulator.AdvanceTo(0.1)"), "docs/architecture.md",
                 "exec"), namespace)
    assert capsys.readouterr().out.split()[-2:] == ["True", "True"]
    assert namespace["context"].get_time() == pytest.approx(0.1)
