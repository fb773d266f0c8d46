"""Runs a whole Sequential Dexterity task: one station scene, the chain controller, and per-object episodes.

:class:`ChainRunner` builds the station of a task family (``building_blocks/chain``: pile box and baseplate;
``tool_positioning/tool_grasp``: the table and the tools), the chain controller of that family's chain
(``diagrams/chains.yaml``) from a chain run directory's checkpoints (missing files: untrained stages, listed in
:attr:`ChainRunner.missing`), and, given a Meshcat, the chain status display (``evaluation/display.py``).
An episode is one block (Search -> retrieve -> Orient -> Grasp -> Insert to a goal on the baseplate) or one tool
(grasp -> reorient): :meth:`start_block` / :meth:`start_tool` set the target and goal and restart the chain,
:meth:`run` steps at the control rate until the object reaches its goal or the time limit.

Success (FACTS.md): a block within 0.02 m and 0.2 rad of its goal (a 180 deg yaw flip counts), let go of and at
rest; a tool within 0.5 rad of its goal orientation (the start pose flipped 180 deg about its long axis).
"""

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from seqdex_drake.chaining.chain import LoadChain
from seqdex_drake.chaining.chain_files import LoadChainCheckpoints, observation_sizes, run_dir_configs
from seqdex_drake.chaining.shipped import ShippedChainError, load_shipped_chain
from seqdex_drake.controller.chain_controller import (
    ChainParams,
    ConnectChainController,
    GetChainPolicies,
    MakeChainController,
    SetChainTarget,
)
from seqdex_drake.controller.switcher import TRIGGERS, SwitcherParams
from seqdex_drake.evaluation.chain_settings import (
    APPROACH_STAGES,
    APPROACH_TIMEOUT,
    BLOCK_REST_HEIGHT,
    BLOCK_TRAVEL_HEIGHT,
    CARRY_GOAL_SYMMETRY,
    CARRY_STAGES,
    DONE_SETTLE,
    FREE_OBJECT_STAGES,
    HANDOVER_SETTLE,
    REENGAGE,
    SWITCH_TRIGGER,
    TIMEOUT_FAMILIES,
)
from seqdex_drake.evaluation.display import ChainStatusDisplay
from seqdex_drake.evaluation.refetch import RetrieveWatch
from seqdex_drake.evaluation.run_types import ChainRunError, Outcome, RunConfig, scenario_text
from seqdex_drake.harness import ResolvePackageUrl
from seqdex_drake.modeling.blocks import BLOCK_SPECS
from seqdex_drake.modeling.tools import TOOL_SPECS
from seqdex_drake.observation_layout import pose_vector, quat_multiply
from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q, p_PalmHc_Palm
from seqdex_drake.robots.arm_ik import PalmIK
from seqdex_drake.scenario import LoadScenario
from seqdex_drake.scene.objects import SceneObjects
from seqdex_drake.scene.piles import BOX_CENTER, BOX_INNER_HALF, LoadPiles
from seqdex_drake.station import MakeControllerPlant, MakeStation, RefreshSampledOutputs
from seqdex_drake.tasks.blocks_common import accessibility_order, retrieve_order
from seqdex_drake.tasks.insert import YAW_FLIP
from seqdex_drake.tasks.registry import default_config
from seqdex_drake.tasks.rewards import quaternion_angle
from seqdex_drake.tasks.scripted.block_retrieve_script import block_extent, in_box
from seqdex_drake.tasks.search import block_type_of
from seqdex_drake.tasks.tools_common import HELD_LIFT, TABLE_TOP, TOOL_XY

#: Task family -> station scenario.
SCENARIOS = {"building_blocks": "building_blocks/chain", "tool_positioning": "tool_positioning/tool_grasp"}
#: A block is placed within these position (m) and rotation (rad) errors of its goal (Insert's success) once the
#: hand has let go of it and it is at rest (:meth:`ChainRunner.is_success`).
BLOCK_TOLERANCE = (0.02, 0.2)
#: A block is at rest below this speed of its origin (m/s) and this angular speed (rad/s).
BLOCK_REST_SPEED = (0.02, 0.2)
TOOL_TOLERANCE = 0.5
#: Where a tool's goal is: lifted this far above its start, held in hand.
TOOL_GOAL_LIFT = 0.15
#: A tool counts as held (the paper: "lifted and held in hand") while its origin is at least this far above its
#: start height: half the goal's lift, so a tool lying on the table (or dropped onto it) never succeeds. Tool
#: Reorient's success uses the same (``tasks/tools_common.HELD_LIFT``), so F learns what the chain counts.
TOOL_HELD_LIFT = HELD_LIFT
#: A plant position (m, quaternion) or velocity (m/s, rad/s) this large means the simulation has diverged.
DIVERGED = 1e3
#: The target object's origin below this world height [m] has fallen off the table (its top is at 0.6 m in both
#: families, and nothing lies below it: a tool the hand knocks off falls for ever, and was once stopped as a
#: diverged simulation 14 s later). Nothing in the chain can reach it there, so the episode ends, failed. Any
#: other object below it is parked (frozen off the table): a pile block knocked off the table fell for 14 s and
#: ended two whole-manual runs as diverged, in the manual's third block.
FELL_BELOW = 0.3
__all__ = ["ChainRunError", "ChainRunner", "Outcome", "RunConfig"]


class ChainRunner:
    """A station + chain controller (+ display) for one task family (see the module docstring).

    Args:
        config: what to build.
        meshcat: optional Meshcat: the scene and the chain status are shown there.
    """

    def __init__(self, config: RunConfig, meshcat=None):
        if config.family not in SCENARIOS:
            raise ChainRunError(f"unknown task '{config.family}'; valid: {', '.join(SCENARIOS)}")
        self.config = config
        try:
            self.tasks = list(LoadChain(config.chain or config.family).stages)
            self._watch = RetrieveWatch(self.tasks, config.refetches)
        except ValueError as error:
            raise ChainRunError(str(error)) from error
        self.scenario = LoadScenario(SCENARIOS[config.family], scenario_text=scenario_text(config))
        stages, feasibility, self.missing = [(task, None) for task in self.tasks], None, []
        stage_configs, self.shipped = None, None
        if config.run_dir is not None and (Path(config.run_dir) / "manifest.json").exists():
            try:  # Shipped checkpoints: checked (files whole, specs, task configs) before anything is built.
                self.shipped = load_shipped_chain(config.run_dir, config.family, self.tasks, observation_sizes())
            except ShippedChainError as error:
                raise ChainRunError(str(error)) from error
            stages, feasibility, self.missing = self.shipped.stages, self.shipped.feasibility, self.shipped.missing
            stage_configs = self.shipped.configs
        elif config.run_dir is not None:
            try:
                found = LoadChainCheckpoints(config.run_dir, self.tasks)
            except FileNotFoundError as error:
                raise ChainRunError(str(error)) from error
            stages, self.missing = found.stages, list(found.missing)
            feasibility = self._feasibility_files(Path(config.run_dir), found.feasibility)
            stage_configs = run_dir_configs(Path(config.run_dir), self.tasks, found.policies)
        else:
            self.missing = [f"stage {i} ({task}): no checkpoint directory given (--checkpoints); the stage runs "
                            f"an untrained policy" for i, task in enumerate(self.tasks)]
        trigger = config.trigger or SWITCH_TRIGGER[config.family]
        if trigger not in TRIGGERS:
            raise ChainRunError(f"unknown switcher trigger '{trigger}'; valid: {', '.join(TRIGGERS)}")
        params = ChainParams(switcher=SwitcherParams(max_switches=config.max_switches,
                                                     stage_steps=config.stage_steps, trigger=trigger),
                             untrained_seed=config.seed, stage_configs=stage_configs,
                             reengage_distance=REENGAGE,
                             travel_height=BLOCK_TRAVEL_HEIGHT if config.family == "building_blocks" else 0.0,
                             approach_stages=self._in_chain(APPROACH_STAGES),
                             approach_timeout=APPROACH_TIMEOUT if config.family in TIMEOUT_FAMILIES else np.inf,
                             carry_stages=CARRY_STAGES.get(config.family, ()),
                             free_object_stages=self._in_chain(FREE_OBJECT_STAGES),
                             carry_goal_symmetry=CARRY_GOAL_SYMMETRY.get(config.family, 0.0))
        params.handover_angle, params.handover_speed = HANDOVER_SETTLE.get(config.family, (np.inf, np.inf))
        if config.untrained_hidden_sizes is not None:
            params.untrained_hidden_sizes = tuple(config.untrained_hidden_sizes)
        builder = DiagramBuilder()
        self.station = builder.AddNamedSystem("station", MakeStation(self.scenario, meshcat=meshcat))
        try:
            controller = MakeChainController(self.scenario, stages, feasibility, params)
        except (ValueError, FileNotFoundError, RuntimeError) as error:
            raise ChainRunError(str(error)) from error
        self.controller = builder.AddNamedSystem("chain", controller)
        ConnectChainController(builder, self.station, self.controller)
        self.display = None
        self._completed = builder.AddNamedSystem("completed", ConstantVectorSource(np.zeros(1)))
        if meshcat is not None:
            self.display = builder.AddNamedSystem("chain_status", ChainStatusDisplay(meshcat, self.tasks))
            builder.Connect(self.controller.GetOutputPort("active_stage"), self.display.GetInputPort("active_stage"))
            builder.Connect(self.controller.GetOutputPort("feasibility_scores"),
                            self.display.GetInputPort("feasibility_scores"))
            builder.Connect(self._completed.get_output_port(), self.display.GetInputPort("completed"))
        self.stage_configs = list(stage_configs) if stage_configs is not None else \
            [default_config(task) for task in self.tasks]
        self._ik = PalmIK(MakeControllerPlant(self.scenario), p_PalmC_Palm=p_PalmHc_Palm)
        self._R_WP_hold = self._ik.palm_pose(np.asarray(self.scenario.robot.arm_home)).rotation()
        self.diagram = builder.Build()
        self.simulator = Simulator(self.diagram)
        ApplySimulatorConfig(self.scenario.simulator_config, self.simulator)
        self.context = self.simulator.get_mutable_context()
        self.objects = SceneObjects(self.station, self.scenario)
        self.plant = self.station.GetSubsystemByName("plant")
        self.policies = GetChainPolicies(self.controller)
        self.untrained = [task for task, policy in zip(self.tasks, self.policies, strict=True) if not policy.trained]
        self.target, self.goal, self.completed = "", np.array([0, 0, 0, 1.0, 0, 0, 0]), 0
        self._start_time = 0.0
        if self.scenario.object_layout == "pile":
            self.restore_pile(config.seed)
        else:
            self.objects.park(self.context)

    def _in_chain(self, settings: dict) -> tuple[str, ...]:
        """The family's entry of ``settings`` (e.g. ``APPROACH_STAGES``) restricted to the stages of this chain."""
        return tuple(task for task in settings.get(self.config.family, ()) if task in self.tasks)

    def _feasibility_files(self, run_dir: Path, found: list) -> list:
        if self.config.history is None:
            return found
        files = [None] + [run_dir / "feasibility" / f"{task}_h{self.config.history}.pt" for task in self.tasks[1:]]
        missing = [str(path) for path in files[1:] if not path.is_file()]
        if missing:
            raise ChainRunError(f"history ablation H = {self.config.history}: missing {', '.join(missing)}")
        return files

    # ------------------------------------------------------------------------------------------- scene
    @property
    def plant_context(self):
        return self.plant.GetMyMutableContextFromRoot(self.context)

    def restore_pile(self, index: int) -> int:
        """Restores cached pile ``index`` (modulo the number cached), every block frozen until targeted; returns
        the cached pile's number."""
        piles = LoadPiles(ResolvePackageUrl(self.scenario.pile_file), self.objects.names)
        self.objects.set_positions(self.context, piles[index % len(piles)],
                                   frozen=np.ones(len(self.objects.names), dtype=bool))
        self._used: set[str] = set()
        return index % len(piles)

    def pick_block(self, block_type: int) -> str:
        """The unused block of ``block_type`` to fetch next, the easiest first, as a perception system choosing
        among identical blocks would: with a retrieve stage in the chain, the easiest to take out of the pile
        (:func:`~seqdex_drake.tasks.blocks_common.retrieve_order`: where the hand fits, uncovered, off the box floor,
        highest), as the retrieve was measured; without one, the easiest to orient and grasp in place
        (:func:`~seqdex_drake.tasks.blocks_common.accessibility_order`: also upright, room to roll)."""
        if block_type not in BLOCK_SPECS:
            raise ChainRunError(f"unknown block type {block_type}; valid types: {sorted(BLOCK_SPECS)}")
        q = self.objects.positions(self.context)
        rows = [self.objects.index(n) for n in self.objects.names
                if n.startswith(f"block_{block_type}_") and n not in self._used]
        if not rows:
            raise ChainRunError(f"no block of type {block_type} left in the box (all 9 used)")
        blocks = [self.objects.index(n) for n in self.objects.names if n.startswith("block_")]
        order_of = retrieve_order if "retrieve" in self.tasks else accessibility_order
        order = order_of(q[blocks], [blocks.index(row) for row in rows])
        return self.objects.names[blocks[order[0]]]

    def _reset_robot(self, arm_q=None) -> None:
        plant, context = self.plant, self.plant_context
        arm_q = self.scenario.robot.arm_home if arm_q is None else arm_q
        for name, q in (("franka", arm_q), ("allegro", ALLEGRO_OPEN_Q)):
            instance = plant.GetModelInstanceByName(name)
            plant.SetPositions(context, instance, np.asarray(q, dtype=float))
            plant.SetVelocities(context, instance, np.zeros(plant.num_velocities(instance)))

    def _start(self, name: str, goal: np.ndarray, reset_robot: bool, approach_offset=None, arm_q=None,
               rest_height=None) -> None:
        if reset_robot:
            self._reset_robot(arm_q)
        self.target, self.goal = name, np.asarray(goal, dtype=float)
        body = self.objects.bodies[self.objects.index(name)]
        SetChainTarget(self.controller, self.context, int(body.index()), goal=self.goal,
                       approach_offset=approach_offset, rest_height=rest_height)
        self.simulator.Initialize()  # Restarts the chain at stage 0 (switcher, policies, router, wrist IK).
        self._watch.restart()
        RefreshSampledOutputs(self.plant, self.plant_context)  # Motor torques and contacts of the start state.
        self._start_time = self.context.get_time()

    def start_block(self, block_type: int, goal: np.ndarray, reset_robot: bool = False, name: str = "") -> str:
        """Targets the next block of ``block_type`` in the pile (``name``: that block, e.g. one a retrieve set
        down) with goal pose ``goal`` ([xyz, wxyz]); blocks far from it stay frozen. Returns the block's name."""
        if name and not name.startswith(f"block_{block_type}_"):
            raise ChainRunError(f"block {name!r} is not of type {block_type}; name a block_{block_type}_<k>")
        self._watch.start_object()
        return self._fetch(block_type, goal, reset_robot, name or self.pick_block(block_type))

    def _fetch(self, block_type: int, goal: np.ndarray, reset_robot: bool, name: str) -> str:
        self._used.add(name)
        frozen = self.objects.frozen_mask(self.context)
        p = self.objects.positions(self.context)[:, 4:]
        near = np.linalg.norm(p - p[self.objects.index(name)], axis=1) <= self.scenario.freeze.active_radius
        in_box = np.all(np.abs(p[:, :2] - BOX_CENTER[:2]) <= BOX_INNER_HALF + 0.01, axis=1)
        wake = near & in_box
        wake[self.objects.index(name)] = True  # The target itself, also outside the box (set down by a retrieve).
        self.objects.set_frozen(self.context, frozen & ~wake)
        self._start(name, goal, reset_robot, rest_height=TABLE_TOP + BLOCK_REST_HEIGHT)
        return name

    def refetch(self) -> bool:
        """Fetches the next block of the target's type (``evaluation/refetch.py``), the episode's clock running on;
        False if none is left."""
        block_type = block_type_of(self.target)
        try:
            name = self.pick_block(block_type)
        except ChainRunError:
            return False
        clock = self._start_time
        self._fetch(block_type, self.goal, False, name)
        self._start_time, self._watch.used = clock, self._watch.used + 1
        return True

    @property
    def refetches(self) -> int:
        """Blocks fetched after the first in the current object's episode (:meth:`refetch`)."""
        return self._watch.used

    def target_in_pile(self) -> bool:
        """Whether the target block's centre is still over the box's floor: not taken out of the pile."""
        X_WB = self.object_pose()
        length = float(BLOCK_SPECS[block_type_of(self.target)].footprint[0])
        return in_box(block_extent(X_WB.translation(), X_WB.rotation().matrix(), length)[0])

    def restart(self) -> None:
        """Restarts the chain (stage 0, the approach first) on the current target and goal, the scene as it is now
        (e.g. after moving objects by hand)."""
        self._start(self.target, self.goal, reset_robot=False)

    def start_tool(self, tool_index: int, rng: np.random.Generator) -> str:
        """Lays tool ``tool_index`` (0 hammer: trained; 1 spatula, 2 spoon: unseen) on the table at a random yaw
        (+-45 deg), the others parked; the goal is its start pose flipped 180 deg about its long axis, lifted.
        The hand starts where tool Grasp's env starts it (``tasks/tools_common.place_tool_on_table``): open,
        palm down, its centre ``hover_height`` above the tool's top; the approach there is done, so tool Grasp
        acts from the first tick, and its scripted grasp starts from the pose it was designed and trained from.
        Returns the tool's name."""
        names = list(TOOL_SPECS)
        if not 0 <= tool_index < len(names):
            raise ChainRunError(f"unknown tool {tool_index}; valid: {dict(enumerate(names))}")
        name = names[tool_index]
        self.objects.park(self.context)
        height = TOOL_SPECS[name].bounding_box[2]
        X_WT = RigidTransform(RollPitchYaw(0.0, 0.0, rng.uniform(-np.pi / 4, np.pi / 4)),
                              [*TOOL_XY, TABLE_TOP + height / 2 + 0.002])
        self.objects.set_pose(self.context, name, X_WT, frozen=False)
        X_goal = RigidTransform(X_WT.rotation() @ RotationMatrix.MakeYRotation(np.pi),
                                X_WT.translation() + [0.0, 0.0, TOOL_GOAL_LIFT])
        # The approach (after a restart) hovers the hand over the tool's top, where tool Grasp's env starts it.
        offset = np.array([0.0, 0.0, height / 2])
        body = self.objects.bodies[self.objects.index(name)]
        p_WH = X_WT @ body.default_com() + offset + [0.0, 0.0, self.stage_configs[0].hover_height]
        arm_q, error = self._ik.solve(np.asarray(self.scenario.robot.arm_home), p_WH, self._R_WP_hold)
        if error > 0.01:
            raise ChainRunError(f"the hover pose above {name} ({np.round(p_WH, 3)}) is out of reach ({error:.3f} m)")
        self._start(name, pose_vector(X_goal), reset_robot=True, approach_offset=offset, arm_q=arm_q,
                    rest_height=float((X_WT @ body.default_com())[2]))
        return name

    def set_completed(self, count: int) -> None:
        """The finished-object count shown by the display."""
        self.completed = int(count)
        source = self._completed.get_mutable_source_value(self._completed.GetMyMutableContextFromRoot(self.context))
        source.SetFromVector([float(count)])

    # ----------------------------------------------------------------------------------------- running
    def object_pose(self) -> RigidTransform:
        body = self.objects.bodies[self.objects.index(self.target)]
        return self.plant.EvalBodyPoseInWorld(self.plant_context, body)

    def errors(self) -> tuple[float, float]:
        """Position (m) and rotation (rad) errors of the target to its goal (blocks: yaw-flip symmetric)."""
        pose = pose_vector(self.object_pose())
        rotation = quaternion_angle(pose[3:], self.goal[3:])
        if self.config.family == "building_blocks":
            rotation = min(rotation, quaternion_angle(pose[3:], quat_multiply(self.goal[3:], YAW_FLIP)))
        return float(np.linalg.norm(pose[:3] - self.goal[:3])), float(rotation)

    def is_success(self) -> bool:
        """Blocks: the target within ``BLOCK_TOLERANCE`` of its goal, out of the hand's touch and at rest
        (``BLOCK_REST_SPEED``): a block pinched 2 cm over its goal, or falling through the tolerance, is not placed.
        Tools: within ``TOOL_TOLERANCE`` of the goal's rotation and lifted at least ``TOOL_HELD_LIFT``."""
        position, rotation = self.errors()
        if self.config.family == "building_blocks":
            if position >= BLOCK_TOLERANCE[0] or rotation >= BLOCK_TOLERANCE[1]:
                return False
            body = self.objects.bodies[self.objects.index(self.target)]
            V_WB = self.plant.EvalBodySpatialVelocityInWorld(self.plant_context, body)
            return bool(np.linalg.norm(V_WB.translational()) < BLOCK_REST_SPEED[0] and np.linalg.norm(
                V_WB.rotational()) < BLOCK_REST_SPEED[1] and not self.objects.touches_robot(self.plant_context,
                                                                                              self.target))
        held = self.object_pose().translation()[2] > self.goal[2] - TOOL_GOAL_LIFT + TOOL_HELD_LIFT
        return rotation < TOOL_TOLERANCE and held

    def chain_output(self, name: str) -> np.ndarray:
        return self.controller.GetOutputPort(name).Eval(self.controller.GetMyContextFromRoot(self.context))

    def run(self, time_limit: float, on_tick: Callable[["ChainRunner"], bool] | None = None,
            stop_on_success: bool = True, stop_when_done: bool = True) -> Outcome:
        """Steps control periods until success (if ``stop_on_success``), ``time_limit`` simulated seconds from
        the episode's start, ``on_tick`` returning False (called after every step), the family's ``DONE_SETTLE``
        after the chain is done (if ``stop_when_done``; :meth:`chain_done_for`), the target object falling off the
        table (a failed outcome with ``fell``), or a simulator failure (a failed outcome naming it)."""
        period = self.scenario.control_period
        settle = DONE_SETTLE.get(self.config.family) if stop_when_done else None
        settle_ticks = None if settle is None else int(round(settle / period))
        while self.context.get_time() - self._start_time < time_limit - 1e-9:
            try:
                self.simulator.AdvanceTo(self.context.get_time() + period)
            except (RuntimeError, SystemExit) as error:  # A failed contact solve, a non-finite state: pydrake
                # raises its failed assertions as SystemExit. The episode fails; the next start resets the scene.
                return self._outcome(False, (float("nan"), float("nan")), str(error).splitlines()[0])
            state = self.plant.GetPositionsAndVelocities(self.plant_context)
            if not np.all(np.abs(state) < DIVERGED):  # Also catches NaN. Blown-up but finite states would
                # otherwise overflow the wake check's float arithmetic.
                return self._outcome(False, (float("nan"), float("nan")),
                                     f"the simulation diverged at t = {self.context.get_time():.3f} s (a plant "
                                     f"position or velocity beyond {DIVERGED:g})")
            self.objects.update(self.context)
            if self.object_pose().translation()[2] < FELL_BELOW:
                return dataclasses.replace(self._outcome(False, self.errors()), fell=True)
            fallen = self.objects.fallen(self.context, FELL_BELOW, state)
            if fallen:  # Other objects knocked off the table leave the scene (parked) instead of falling for ever
                self.objects.park(self.context, fallen)  # until the state diverges (a pile block, 14 s later).
            if self._watch.due(int(self.chain_output("active_stage")[0]), self.target_in_pile):
                self.refetch()
            if on_tick is not None and on_tick(self) is False:
                break
            if stop_on_success and self.is_success():
                break
            if settle_ticks is not None and self.chain_done_for() >= settle_ticks:
                break
        return self._outcome(self.is_success(), self.errors())

    def chain_done_for(self) -> int:
        """Control ticks since the chain was done (its last stage past its budget, no switch to restart a stage:
        ``FeasibilitySwitcher.done_for``); 0 while it is not."""
        switcher = self.controller.GetSubsystemByName("switcher")
        return switcher.done_for(switcher.GetMyContextFromRoot(self.context))

    def _outcome(self, success: bool, errors: tuple[float, float], simulator_error: str = "") -> Outcome:
        return Outcome(success=success, time=self.context.get_time() - self._start_time,
                       last_stage=int(self.chain_output("active_stage")[0]),
                       switches=int(self.chain_output("switches_used")[0]), position_error=errors[0],
                       rotation_error=errors[1], simulator_error=simulator_error, refetches=self._watch.used)

    def episode_limit(self) -> float:
        """A time limit covering every stage's budget once per allowed switch, plus ``APPROACH_TIMEOUT`` per
        approach (the first, and one per approach or carry stage)."""
        switcher = self.controller.GetSubsystemByName("switcher")
        family = self.config.family
        approaches = 1 + len(self._in_chain(APPROACH_STAGES)) + len(CARRY_STAGES.get(family, ()))
        return float(np.sum(switcher.stage_budgets)) * (1 + self.config.max_switches) * \
            self.scenario.control_period + APPROACH_TIMEOUT * approaches
