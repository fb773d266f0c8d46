"""The chain controller executes a policy as its sub-task env does: from the env's reset state and with the same
actions, the Drake chain (policy system, router, wrist IK, station) moves the palm along the env's path, one
control tick later (the approach hands over at the first tick). A policy trained in the env then works in the
chain; before the wrist integrator fed the target's velocity forward, the palm lagged by centimetres."""

import numpy as np
import torch
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator
from pydrake.systems.framework import DiagramBuilder

from seqdex_drake.controller.chain_controller import (
    ChainParams,
    ConnectChainController,
    MakeChainController,
    SetChainTarget,
)
from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.modeling.tools import TOOL_SPECS
from seqdex_drake.observation_layout import PALM_POSE
from seqdex_drake.rl.networks import ActorCritic
from seqdex_drake.scene.objects import SceneObjects
from seqdex_drake.station import MakeStation
from seqdex_drake.tasks.registry import default_config

ACTION = np.r_[np.linspace(-0.5, 0.5, 16), 0.8, -0.6, 0.4]  # Fingers closing a little, the wrist moving.
TICKS = 30


def constant_policy(obs_dim: int) -> ActorCritic:
    """A policy whose mean action is ACTION whatever it observes."""
    model = ActorCritic(obs_dim, 19, actor_hidden_sizes=(8,), critic_hidden_sizes=(8,))
    with torch.no_grad():
        last = model.actor[-1]
        last.weight.zero_()
        last.bias.copy_(torch.as_tensor(ACTION, dtype=torch.float32))
    return model


def test_the_chain_moves_the_palm_as_the_env_does():
    config = default_config("tool_grasp")
    env = make_env("tool_grasp", config)
    observation, _ = env.reset(seed=0)
    X_WB = env.plant.EvalBodyPoseInWorld(env.plant_context, env.object_body())  # The body frame, not the COM's.
    robot = {name: env.plant.GetPositions(env.plant_context, env.plant.GetModelInstanceByName(name))
             for name in ("franka", "allegro")}
    palms = [observation[PALM_POSE][:3]]
    for _ in range(TICKS):
        observation, *_ = env.step(ACTION)
        palms.append(observation[PALM_POSE][:3])
    palms = np.array(palms)
    assert np.linalg.norm(palms[-1] - palms[0]) > 0.05  # The wrist really moved.

    # The same start in the chain: tool, arm and hand as the env's reset left them.
    scenario = env.scenario
    builder = DiagramBuilder()
    station = builder.AddNamedSystem("station", MakeStation(scenario))
    controller = builder.AddNamedSystem("chain", MakeChainController(
        scenario, [("tool_grasp", constant_policy(env.observation_space.shape[0]))],
        params=ChainParams(stage_configs=[config], reengage_distance=float("inf"))))  # As the tool chain.
    ConnectChainController(builder, station, controller)
    simulator = Simulator(builder.Build())
    ApplySimulatorConfig(scenario.simulator_config, simulator)
    context = simulator.get_mutable_context()
    objects = SceneObjects(station, scenario)
    objects.park(context)
    objects.set_pose(context, env.target_object, X_WB, frozen=False)
    plant = station.GetSubsystemByName("plant")
    plant_context = plant.GetMyMutableContextFromRoot(context)
    for name, q in robot.items():
        plant.SetPositions(plant_context, plant.GetModelInstanceByName(name), q)
    body = objects.bodies[objects.index(env.target_object)]
    height = TOOL_SPECS[env.target_object].bounding_box[2]
    SetChainTarget(controller, context, int(body.index()), approach_offset=[0.0, 0.0, height / 2])
    simulator.Initialize()
    assembler = controller.GetSubsystemByName("observation.base")
    chain = []
    for tick in range(TICKS + 2):
        simulator.AdvanceTo(tick * scenario.control_period)
        chain.append(assembler.GetOutputPort("observation").Eval(assembler.GetMyContextFromRoot(context))[PALM_POSE][:3])
    assert controller.GetOutputPort("approach_active").Eval(controller.GetMyContextFromRoot(context))[0] == 0.0
    # Tick k + 1 of the chain is step k of the env (the approach used the first tick to hand over).
    errors = np.linalg.norm(np.array(chain[1:TICKS + 2]) - palms, axis=1)
    assert errors.max() < 0.003, errors.round(4)
