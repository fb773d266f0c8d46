"""The chained sub-policies as one controller Diagram that plugs into the station by port name.

:func:`MakeChainController` builds, for a list of stages (registered task name, policy checkpoint or None):
one :class:`~seqdex_drake.sensors.observations.ObservationAssembler` per observation layout, one
:class:`~seqdex_drake.controller.policy.PolicySystem` per stage, the
:class:`~seqdex_drake.controller.switcher.FeasibilitySwitcher`, the
:class:`~seqdex_drake.control.osc.OperationalSpaceController` (hand centre to 5 cm above the target while
it is farther than 5 cm), a :class:`~seqdex_drake.controller.chain_parts.StageRouter`, the approach target and
the wrist IK (:class:`~seqdex_drake.controller.chain_parts.WristTargetIntegrator`). Ports, station-side names:

Inputs
    ``plant_state``, ``allegro.net_actuation``, ``franka.state``, ``body_poses``,
    ``label_image`` (only with a Search stage: the station's ``<camera>.label_image``), ``stage_success``
    (optional, 1: the executing stage succeeded; leave unconnected to use the step budgets only).
Outputs
    ``franka.desired_state`` (14), ``allegro.desired_state`` (32), ``active_stage`` (1, 0-based index into
    ``stages``), ``feasibility_scores`` (K, c^i; NaN where undefined), ``executing_stage`` (1),
    ``approach_active`` (1), ``action`` (19, applied), ``switches_used`` (1), ``approach_target`` (3).

The chain's target (block body index, goal pose) is a parameter of the context: call :func:`SetChainTarget`
after creating the context and before simulating.
:func:`~seqdex_drake.chaining.chain_files.LoadChainCheckpoints` finds a chain run's files.
Several controllers in one diagram need distinct names: ``MakeChainController(..., name=...)`` names the
Diagram and prefixes its Meshcat marker's path, as ``MakeStation``'s ``name`` does for a station.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence

import numpy as np
import torch
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import Context, Diagram, DiagramBuilder
from pydrake.systems.primitives import Adder

from seqdex_drake.chaining.chain_files import check_chain_task
from seqdex_drake.chaining.feasibility_io import FeasibilityFile, load_feasibility
from seqdex_drake.control.osc import OperationalSpaceController, OscParams
from seqdex_drake.controller.chain_parts import ApproachTarget, ChainMarker, StageRouter, WristTargetIntegrator
from seqdex_drake.controller.inference import limit_blas_threads
from seqdex_drake.controller.policy import PAPER_HIDDEN_SIZES, PolicyParams, PolicySystem
from seqdex_drake.controller.switcher import FeasibilitySwitcher, SwitcherParams
from seqdex_drake.rl.networks import ActorCritic
from seqdex_drake.robots.allegro import p_PalmHc_Palm
from seqdex_drake.robots.arm_ik import PalmIK
from seqdex_drake.scenario import Scenario
from seqdex_drake.sensors.observations import ObservationAssembler, ObservationTarget
from seqdex_drake.station import AddStationPlant, CheckSystemName, MakeControllerPlant, MeshcatPath
from seqdex_drake.tasks.registry import REGISTRY, default_config
from seqdex_drake.tasks.run_config import observation_spec

STATION_INPUTS = ("plant_state", "allegro.net_actuation", "franka.state", "body_poses")
"""Station outputs every chain controller reads (plus ``<camera>.label_image`` with a Search stage)."""
_ASSEMBLER_INPUTS = ("plant_state", "allegro.net_actuation")


@dataclasses.dataclass
class ChainParams:
    """Parameters of :func:`MakeChainController`."""

    ema: float | None = None
    """EMA factor of every policy's hand action; None: each task's training value (``TaskConfig.ema``). The
    paper deploys with 0.2 (``seqdex_drake.controller.policy.DEPLOYMENT_EMA``)."""
    switcher: SwitcherParams = dataclasses.field(default_factory=SwitcherParams)
    """Switch cap, per-stage step budgets (default: each task's ``episode_length``), decision rule."""
    osc: OscParams | None = None
    """Approach controller parameters; None: ``OscParams`` with the controlled point at the hand centre (the
    point the sub-task resets place 5 cm above the target) and ``solve_while_handed_over=False`` (no QP while a
    policy drives the arm)."""
    untrained_seed: int = 0
    """Stage i without a checkpoint gets a freshly initialised policy seeded ``untrained_seed + i``."""
    untrained_hidden_sizes: tuple[int, ...] = PAPER_HIDDEN_SIZES
    """Actor hidden sizes of untrained policies."""
    torch_threads: int | None = 1
    """If set, ``torch.set_num_threads`` (process-wide!) when the controller is built: batch-1 inference is
    fastest on one thread, and spinning OpenMP workers compete with the simulation for the cores (measured:
    an F forward pass took 25 ms with 2 threads and 4 ms with 1 on a loaded 2-core machine). None: leave it."""
    blas_threads: int | None = 1
    """If set, numpy's BLAS thread count (process-wide!, :func:`~seqdex_drake.controller.inference.limit_blas_threads`)
    when the controller is built: the numpy inference path's batch-1 products ran 0.09 ms on 1 OpenBLAS thread
    and 6 ms on the default 2 on the loaded 2-core machine. None: leave it."""
    inference: str = "numpy"
    """Inference path of the policies and the switcher's F's: "numpy" (float32 snapshots, fast at batch 1) or
    "torch" (the models themselves); overrides ``switcher.inference``."""
    reengage_distance: float | None = None
    """If set, the approach's ``OscParams.reengage_distance``: how far (m) the target may get from the hand while a
    stage runs before the approach takes over again (``inf``: never within a stage; a feasibility switch still
    restarts it). The chains use ``inf``: tool Grasp's script moves the hand more than 0.1 m from the tool's top on
    purpose, block Search's 14-17 cm aside of its target."""
    travel_height: float = 0.0
    """The approach's ``OscParams.travel_height``: a world height (m) the hand crosses at between workspaces (the
    Building Blocks chain: over the box walls between the baseplate and the pile); 0: straight lines."""
    approach_timeout: float = float("inf")
    """The approach's ``OscParams.approach_timeout``: seconds after which an approach that has not reached the hover
    point hands over where the hand is (the stage's clock stops while the approach runs)."""
    handover_angle: float = float("inf")
    """The approach's ``OscParams.handover_angle``: it hands over only with the hand within this angle (rad) of the
    orientation it holds (a carry's turn included)."""
    handover_speed: float = float("inf")
    """The approach's ``OscParams.handover_speed``: it hands over only with the hand centre slower than this (m/s)."""
    approach_stages: tuple[str, ...] = ()
    """Tasks whose stage, entered in sequence, starts with the approach bringing the hand back to the hover point
    (where its policy's resets put it), as after a feasibility switch. Empty: the previous stage's terminal state
    is the next one's start (the paper's forward initialization)."""
    carry_stages: tuple[tuple[str, float], ...] = ()
    """(task, height) pairs: stages with a goal that, entered in sequence, start with the approach carrying the held
    object until its origin is ``height`` (m) above its goal, the previous stage's hand kept closed
    (:class:`~seqdex_drake.controller.chain_parts.ApproachTarget`, ``StageRouter(hold_hand=)``). Block Insert: from
    Grasp's lift (about 1.1 m, anywhere over the box) to the baseplate is more than its 125 steps at the wrist's
    0.3 m/s."""
    free_object_stages: tuple[str, ...] = ()
    """Tasks whose stage a feasibility switch may select only while the target object is not lifted in hand
    (``SwitcherParams.free_object_stages``, from ``ApproachTarget``'s ``object_lifted``; the target's
    ``rest_height``, :func:`SetChainTarget`). Tool Grasp: it starts from the tool on the table."""
    carry_goal_symmetry: float = 0.0
    """If > 0, the carry also turns the hand until the held object takes its goal's orientation, the goal counting
    the same turned about its z by multiples of this angle [rad], and the stage's wrist IK keeps that turn
    (``ApproachTarget``'s ``hold_rotation``). Building Blocks: pi (a block turned by pi seats the same), as Grasp's
    jaws leave the block 10-15 deg off its yaw and tilted along its length, and the policies' wrist actions are
    translations. 0: the palm keeps its orientation."""
    stage_configs: Sequence | None = None
    """Each stage's :class:`~seqdex_drake.tasks.base.TaskConfig` as its policy was trained (EMA, wrist step,
    episode length, scripted phases; ``seqdex_drake.chaining.shipped`` records them); None: the tasks' defaults."""


def _layout(task: str) -> tuple[bool, bool]:
    task_class = REGISTRY[task][1]
    return bool(task_class.goal), bool(task_class.pixels)


def _make_policy(index: int, task: str, policy, size: int, params: PolicyParams, chain: ChainParams,
                 body_names: list[str]) -> PolicySystem:
    if REGISTRY[task][1].scripted:
        if policy is not None:
            raise ValueError(f"stage {index} ({task}) is scripted (its base acts alone, nothing is trained): its "
                             f"policy must be None, got {policy!r}")
        return PolicySystem.scripted(size, params, body_names)
    if policy is None:
        return PolicySystem.untrained(size, chain.untrained_seed + index, params, chain.untrained_hidden_sizes)
    if isinstance(policy, ActorCritic):
        return PolicySystem(policy, size, params, trained=True, source=f"in-memory model of stage {index} ({task})")
    if isinstance(policy, str | os.PathLike):
        return PolicySystem.from_checkpoint(policy, size, params)
    raise TypeError(f"stage {index} ({task}): the policy must be a checkpoint path, an ActorCritic or None, "
                    f"got {type(policy).__name__}")


def StagePolicyParams(config, control_period: float, inference: str = "numpy", ema: float | None = None
                      ) -> PolicyParams:
    """The :class:`PolicyParams` that run a policy as its stage's env trained it (``config``, a
    :class:`~seqdex_drake.tasks.base.TaskConfig`): its EMA (``ema`` overrides), wrist step, scripted phases,
    progress input and residual base."""
    return PolicyParams(control_period=control_period, ema=config.ema if ema is None else ema,
                        wrist_step=config.wrist_step, inference=inference, phases=config.phases,
                        time_steps=config.episode_length if config.observe_time else 0, residual=config.residual)


def _load_f(index: int, tasks: list[str], entry, sizes: list[int]) -> FeasibilityFile | None:
    """Stage ``index``'s F, checked against the chain (target task, source task, observation size)."""
    if entry is None:
        return None
    if index == 0:
        raise ValueError(f"stage 0 ({tasks[0]}) has no predecessor, so feasibility[0] must be None")
    task, previous = tasks[index], tasks[index - 1]
    if isinstance(entry, str | os.PathLike):
        where = str(entry)
        entry = load_feasibility(entry, observation_spec(previous, sizes[index - 1]), expected_target_task=task)
    else:
        where = f"the in-memory feasibility function of stage {index}"
    source = getattr(entry, "source_task", previous)
    if source != previous:
        raise ValueError(f"{where} scores histories of task {source!r}, but stage {index} ({task}) follows "
                         f"{previous!r}; use the F trained on {previous} -> {task} transitions")
    return entry


def MakeChainController(scenario: Scenario, stages: Sequence[tuple[str, object]], feasibility: Sequence | None = None,
                        params: ChainParams | None = None, meshcat=None, name: str | None = None) -> Diagram:
    """Builds the chain controller Diagram for ``scenario`` (see the module docstring for its ports).

    Args:
        scenario: the scenario of the station it will drive (plant layout, control period, gains, home).
        stages: K pairs (registered task name, policy): a PPO checkpoint path, an in-memory ``ActorCritic``, or
            None for an untrained policy (``PolicySystem.trained`` is False; the chain still runs).
        feasibility: None (no F at all: sequential execution) or K entries, entry 0 None, entry i a path to
            F^i's file, a ``FeasibilityFile``, or None.
        params: EMA, switcher, OSC and untrained-policy settings; defaults to ``ChainParams()``.
        meshcat: optional; draws the approach target coloured by the executing stage (Meshcat path
            ``chain/target``, ``<name>/chain/target`` with a ``name``).
        name: the Diagram's name and the prefix of its Meshcat path; give each controller of one diagram its
            own. None: ``chain_controller``.

    Raises:
        ValueError: an unknown task, a Search stage without a label camera in the scenario, a checkpoint or F
            whose observation size, task or spec does not fit its stage (the message names the file); a
            ``name`` that is empty or contains ``::`` or ``/``.
        FileNotFoundError: a checkpoint or F path that does not exist.
    """
    # Resolved first: the loops below reuse ``name`` for port names.
    prefix = None if name is None else CheckSystemName(name)
    diagram_name = prefix or "chain_controller"
    params = params or ChainParams()
    if params.torch_threads:
        torch.set_num_threads(params.torch_threads)
    if params.blas_threads:
        limit_blas_threads(params.blas_threads)
    tasks = [check_chain_task(task) for task, _ in stages]
    if not tasks:
        raise ValueError("a chain needs at least one stage")
    feasibility = [None] * len(tasks) if feasibility is None else list(feasibility)
    if len(feasibility) != len(tasks):
        raise ValueError(f"feasibility needs one entry per stage ({len(tasks)}), got {len(feasibility)}")
    layouts = [_layout(task) for task in tasks]
    cameras = [name for name, camera in scenario.cameras.items() if camera.label]
    if any(pixels for _, pixels in layouts) and not cameras:
        raise ValueError("a Search stage needs a camera with label images in the scenario (e.g. "
                         "building_blocks/search); this scenario has none")
    configs = [default_config(task) for task in tasks] if params.stage_configs is None else list(params.stage_configs)
    if [config.name for config in configs] != tasks:
        raise ValueError(f"stage_configs are for {[config.name for config in configs]}, the stages are {tasks}")
    period = scenario.control_period

    builder = DiagramBuilder()
    plant, _ = AddStationPlant(DiagramBuilder(), scenario)  # The station's plant layout, for body lookups only.
    assemblers = {}
    for goal, pixels in dict.fromkeys(layouts):
        name = "observation." + ("goal" if goal else "pixels" if pixels else "base")
        assemblers[(goal, pixels)] = builder.AddNamedSystem(name, ObservationAssembler(plant, goal, pixels))
    sizes = [assemblers[layout].size for layout in layouts]
    policies = []
    # Each body's object name (its model instance's, e.g. "block_3_2"), by body index, for target-bound bases.
    body_names = [plant.GetModelInstanceName(plant.get_body(BodyIndex(i)).model_instance())
                  for i in range(plant.num_bodies())]
    for i, ((task, policy), config) in enumerate(zip(stages, configs, strict=True)):
        policy_params = StagePolicyParams(config, period, params.inference, params.ema)
        system = _make_policy(i, task, policy, sizes[i], policy_params, params, body_names)
        policies.append(builder.AddNamedSystem(f"policy.{i}", system))
    # A stage that observes its progress: its F reads histories with the progress appended (the switcher adds it).
    time_steps = tuple(config.episode_length if config.observe_time else 0 for config in configs)
    carry = dict(params.carry_stages)
    unknown = sorted((set(params.approach_stages) | set(carry) | set(params.free_object_stages)) - set(tasks))
    if unknown:
        raise ValueError(f"ChainParams.approach_stages / carry_stages / free_object_stages name {unknown}, not stages "
                         f"of this chain "
                         f"({', '.join(tasks)})")
    f_files = [_load_f(i, tasks, entry, [size + (1 if t else 0) for size, t in zip(sizes, time_steps, strict=True)])
               for i, entry in enumerate(feasibility)]
    switcher_params = dataclasses.replace(params.switcher, inference=params.inference, time_steps=time_steps,
                                          approach_on_entry=tuple(task in params.approach_stages or task in carry
                                                                  for task in tasks),
                                          free_object_stages=tuple(task in params.free_object_stages for task in tasks))
    switcher = builder.AddNamedSystem("switcher", FeasibilitySwitcher(
        f_files, sizes, [config.episode_length for config in configs], period, switcher_params))
    osc_params = params.osc or OscParams(p_PalmPc_Palm=tuple(p_PalmHc_Palm), hover_height=configs[0].hover_height,
                                         solve_while_handed_over=False)
    router = builder.AddNamedSystem("router", StageRouter(len(tasks), period, [task in carry for task in tasks]))
    home = np.asarray(scenario.robot.arm_home, dtype=float)
    ik = PalmIK(MakeControllerPlant(scenario), p_PalmC_Palm=p_PalmHc_Palm)
    R_WP_hold = ik.palm_pose(home).rotation()  # The palm orientation the OSC and the wrist IK hold (the home's).
    hand = (int(plant.GetBodyByName("palm").index()), osc_params.p_PalmPc_Palm, osc_params.hover_height)
    approach = builder.AddNamedSystem("approach_target", ApproachTarget(
        plant, [goal for goal, _ in layouts], [carry.get(task, np.nan) for task in tasks], hand,
        params.carry_goal_symmetry, R_WP_hold))
    if params.reengage_distance is not None:
        osc_params = dataclasses.replace(osc_params, reengage_distance=params.reengage_distance)
    if params.travel_height > 0.0:
        osc_params = dataclasses.replace(osc_params, travel_height=params.travel_height)
    if params.handover_angle < float("inf") or params.handover_speed < float("inf"):
        osc_params = dataclasses.replace(osc_params, handover_angle=params.handover_angle,
                                         handover_speed=params.handover_speed)
    if params.approach_timeout < float("inf"):
        osc_params = dataclasses.replace(osc_params, approach_timeout=params.approach_timeout)
    osc = builder.AddNamedSystem("osc", OperationalSpaceController(
        MakeControllerPlant(scenario), period, scenario.robot.arm_kp, scenario.robot.arm_kd, osc_params, home_q=home))
    wrist = builder.AddNamedSystem("wrist_ik", WristTargetIntegrator(ik, R_WP_hold, period))

    # Station-side inputs, each exported once and fanned out.
    consumers = {name: [a.GetInputPort(name) for a in assemblers.values()] for name in _ASSEMBLER_INPUTS}
    consumers["franka.state"] = [osc.GetInputPort("franka.state"), wrist.GetInputPort("franka.state")]
    consumers["body_poses"] = [approach.GetInputPort("body_poses")]
    if any(pixels for _, pixels in layouts):
        consumers["label_image"] = [a.GetInputPort("label_image") for (_, pixels), a in assemblers.items() if pixels]
    consumers["stage_success"] = [switcher.GetInputPort("stage_success")]
    for name, ports in consumers.items():
        builder.ExportInput(ports[0], name)
        for port in ports[1:]:
            builder.ConnectInput(name, port)

    for assembler in assemblers.values():
        builder.Connect(router.GetOutputPort("raw_action"), assembler.GetInputPort("previous_action"))
    for i, policy in enumerate(policies):
        builder.Connect(assemblers[layouts[i]].GetOutputPort("observation"), policy.GetInputPort("observation"))
        builder.Connect(router.GetOutputPort(f"enable.{i}"), policy.GetInputPort("active"))
        builder.Connect(router.GetOutputPort("raw_action"), policy.GetInputPort("previous_action"))
        builder.Connect(router.GetOutputPort("action"), policy.GetInputPort("previous_filtered_action"))
        for name in ("action", "raw_action", "hand_target", "wrist_translation"):
            builder.Connect(policy.GetOutputPort(name), router.GetInputPort(f"{name}.{i}"))
    for i in range(1, len(tasks)):
        if f_files[i] is not None:
            builder.Connect(assemblers[layouts[i - 1]].GetOutputPort("observation"),
                            switcher.GetInputPort(f"observation.{i - 1}"))
    builder.Connect(osc.GetOutputPort("approach_active"), switcher.GetInputPort("approach_active"))
    scripted = [policy for policy in policies if policy.is_scripted]
    if scripted:  # A scripted stage ends when its script is finished (only the active system's output is 1).
        done = builder.AddNamedSystem("scripted_done", Adder(len(scripted), 1))
        for k, policy in enumerate(scripted):
            builder.Connect(policy.GetOutputPort("finished"), done.get_input_port(k))
        builder.Connect(done.get_output_port(), switcher.GetInputPort("stage_done"))
    # A feasibility switch (or entering an approach stage) (re)starts a stage: the approach brings the hand back
    # above the target first.
    builder.Connect(switcher.GetOutputPort("stage_epoch"), osc.GetInputPort("stage_epoch"))
    builder.Connect(switcher.GetOutputPort("active_stage"), router.GetInputPort("stage"))
    builder.Connect(osc.GetOutputPort("approach_active"), router.GetInputPort("approach_active"))
    builder.Connect(switcher.GetOutputPort("active_stage"), approach.GetInputPort("stage"))
    if params.free_object_stages:
        builder.Connect(approach.GetOutputPort("object_lifted"), switcher.GetInputPort("object_held"))
    builder.Connect(approach.GetOutputPort("target_position"), osc.GetInputPort("target_position"))
    if params.carry_goal_symmetry > 0.0:
        builder.Connect(approach.GetOutputPort("hold_rotation"), osc.GetInputPort("hold_rotation"))
        builder.Connect(approach.GetOutputPort("hold_rotation"), wrist.GetInputPort("hold_rotation"))
    builder.Connect(osc.GetOutputPort("franka.desired_state"), wrist.GetInputPort("osc.desired_state"))
    builder.Connect(router.GetOutputPort("wrist_translation"), wrist.GetInputPort("wrist_translation"))
    builder.Connect(router.GetOutputPort("policy_in_charge"), wrist.GetInputPort("policy_in_charge"))
    if meshcat is not None:
        marker = builder.AddNamedSystem("marker", ChainMarker(meshcat, path=MeshcatPath(prefix, "chain/target")))
        builder.Connect(approach.GetOutputPort("target_position"), marker.GetInputPort("target_position"))
        builder.Connect(router.GetOutputPort("executing_stage"), marker.GetInputPort("stage"))

    for name, port in (("franka.desired_state", wrist.GetOutputPort("franka.desired_state")),
                       ("allegro.desired_state", router.GetOutputPort("allegro.desired_state")),
                       ("active_stage", switcher.GetOutputPort("active_stage")),
                       ("feasibility_scores", switcher.GetOutputPort("feasibility_scores")),
                       ("executing_stage", router.GetOutputPort("executing_stage")),
                       ("approach_active", osc.GetOutputPort("approach_active")),
                       ("action", router.GetOutputPort("action")),
                       ("switches_used", switcher.GetOutputPort("switches_used")),
                       ("approach_target", approach.GetOutputPort("target_position"))):
        builder.ExportOutput(port, name)
    diagram = builder.Build()
    diagram.set_name(diagram_name)
    return diagram


def ConnectChainController(builder: DiagramBuilder, station: Diagram, controller: Diagram) -> None:
    """Connects ``controller`` (from :func:`MakeChainController`) to ``station`` (from ``MakeStation``) by name:
    every controller input except ``stage_success`` from the station output of the same name (``label_image``
    from the station's only ``<camera>.label_image``), and the two desired states back."""
    for index in range(controller.num_input_ports()):
        name = controller.get_input_port(index).get_name()
        if name == "stage_success":
            continue
        if name == "label_image":
            found = [station.get_output_port(i).get_name() for i in range(station.num_output_ports())
                     if station.get_output_port(i).get_name().endswith(".label_image")]
            if len(found) != 1:
                raise ValueError(f"the chain's Search stage needs exactly one '<camera>.label_image' station "
                                 f"output, found {found or 'none'}; connect 'label_image' yourself")
            name_out = found[0]
        else:
            name_out = name
        builder.Connect(station.GetOutputPort(name_out), controller.get_input_port(index))
    for name in ("franka.desired_state", "allegro.desired_state"):
        builder.Connect(controller.GetOutputPort(name), station.GetInputPort(name))


def SetChainTarget(controller: Diagram, root_context: Context, object_body: int, goal: np.ndarray | None = None,
                   label: int | None = None, approach_offset=None, rest_height: float | None = None) -> None:
    """Sets the chain's target in ``root_context`` (the context of the Diagram holding ``controller``, or of
    ``controller`` itself): the target object's body index in the station's plant (e.g.
    ``int(plant.GetBodyByName("block_2").index())``), its goal pose ``[x, y, z, qw, qx, qy, qz]`` (stages
    with a goal: Insert, tool Reorient; also the approach target of those stages) and its render label
    (default: the body index, which is how the station's plant labels geometry). ``approach_offset`` (3, m, world):
    where the approach aims relative to the object's centre of mass in stages without a goal (default 0).
    ``rest_height`` (m): the world height of the object's centre of mass at rest, where it starts (default: unknown;
    ``ChainParams.free_object_stages`` then never block a switch)."""
    target = ObservationTarget(object_body=int(object_body), label=int(object_body if label is None else label))
    if rest_height is not None:
        if not np.isfinite(rest_height):
            raise ValueError(f"rest_height must be a finite height (m), got {rest_height}")
        target.rest_height = float(rest_height)
    if approach_offset is not None:
        offset = np.asarray(approach_offset, dtype=float)
        if offset.shape != (3,) or not np.all(np.isfinite(offset)):
            raise ValueError(f"approach_offset must be a finite 3-vector (m), got {approach_offset}")
        target.approach_offset = offset
    if goal is None and controller.HasSubsystemNamed("observation.goal"):
        raise ValueError("this chain has a stage with a goal pose (Insert / tool Reorient): pass goal=[x, y, z, qw, "
                         "qx, qy, qz] to SetChainTarget")
    if goal is not None:
        goal = np.asarray(goal, dtype=float)
        if goal.shape != (7,) or not np.all(np.isfinite(goal)):
            raise ValueError(f"goal must be a finite pose [x, y, z, qw, qx, qy, qz], got {goal}")
        target.goal = goal
    approach = controller.GetSubsystemByName("approach_target")
    approach.set_target(approach.GetMyMutableContextFromRoot(root_context), target)
    for policy in GetChainPolicies(controller):  # Scripted stages bind their base to the target (the retrieve).
        policy.set_target_body(policy.GetMyMutableContextFromRoot(root_context), int(object_body))
    for name in ("observation.base", "observation.goal", "observation.pixels"):
        if controller.HasSubsystemNamed(name):
            assembler = controller.GetSubsystemByName(name)
            assembler.set_target(assembler.GetMyMutableContextFromRoot(root_context), target)


def GetChainPolicies(controller: Diagram) -> list[PolicySystem]:
    """The controller's PolicySystems in stage order (``trained`` and ``source`` say what each one runs)."""
    policies, i = [], 0
    while controller.HasSubsystemNamed(f"policy.{i}"):
        policies.append(controller.GetSubsystemByName(f"policy.{i}"))
        i += 1
    return policies
