"""A gymnasium environment for one sub-task over a Drake Simulator of the station.

Action (19, in [-1, 1]): 16 Allegro joint targets scaled to the joint limits and EMA-smoothed, then the 3D
wrist translation of the hand centre (``wrist_step`` m per step at 1), tracked by damped least-squares IK
with the palm orientation held (as the release does). Observation: the paper's table for the sub-task
(:mod:`seqdex_drake.observation_layout`). Time limits and simulator failures are truncations; task failure
(the object left the table) is a termination. ``info`` carries every reward term, ``success`` and flags.
"""

import functools
import math

import gymnasium as gym
import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, Demultiplexer

from seqdex_drake.env_state import EnvState
from seqdex_drake.envs import scene_handoff
from seqdex_drake.envs.randomization import DomainRandomizer
from seqdex_drake.observation_layout import (
    ACTION_SIZE,
    FINGERTIPS,
    MOTOR_TACTILE,
    OBJECT_POSE,
    PALM_POSE,
    floats,
    point_in_world,
)
from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q, ALLEGRO_Q_MAX, ALLEGRO_Q_MIN, p_PalmHc_Palm, p_PalmPc_Palm
from seqdex_drake.robots.arm_ik import PalmIK
from seqdex_drake.scene.objects import SceneObjects
from seqdex_drake.sensors.observations import ObservationAssembler, ObservationTarget
from seqdex_drake.sensors.target_pixels import TargetPixelCounter
from seqdex_drake.station import MakeControllerPlant, MakeStation, RefreshSampledOutputs
from seqdex_drake.tasks.base import Task, TaskConfig
from seqdex_drake.tasks.phases import apply_phases
from seqdex_drake.tasks.registry import make_task
from seqdex_drake.tasks.residual import apply_residual, bind_base, make_base

COMMAND_SIZE = 14 + 32 + ACTION_SIZE
"""The env's per-step command source: arm desired state (14), hand desired state (32), previous action."""
_HAND_LOW, _HAND_RANGE = ALLEGRO_Q_MIN.tolist(), (ALLEGRO_Q_MAX - ALLEGRO_Q_MIN).tolist()
_FLOAT32_MAX = float(np.finfo(np.float32).max)
_P_PALM_CENTRE = floats(p_PalmPc_Palm)
_ZEROS_7, _ZEROS_16 = [0.0] * 7, [0.0] * 16


@functools.cache
def _reward_key(term: str) -> str:
    """The ``info`` key of a reward term."""
    return f"reward/{term}"


class SubtaskEnv(gym.Env):
    """One sub-task as a gymnasium environment.

    Args:
        task: a :class:`~seqdex_drake.tasks.base.Task` (see ``seqdex_drake.tasks.registry.make_task``).
        meshcat: optional Meshcat for visualization (never in training workers).
    """

    metadata = {"render_modes": []}

    def __init__(self, task: Task, meshcat=None):
        self.task = task
        self.config: TaskConfig = task.config
        self.scenario = self.config.load_scenario()
        builder = DiagramBuilder()
        station = builder.AddNamedSystem("station", MakeStation(self.scenario, meshcat=meshcat))
        self.plant = station.GetSubsystemByName("plant")
        # What the env writes each step, in one source (one write per step): the arm's and the hand's desired
        # states and the previous action, split in the diagram.
        self._command_source = builder.AddNamedSystem("commands", ConstantVectorSource(np.zeros(COMMAND_SIZE)))
        split = builder.AddNamedSystem("commands.split", Demultiplexer([14, 32, ACTION_SIZE]))
        builder.Connect(self._command_source.get_output_port(), split.get_input_port())
        builder.Connect(split.get_output_port(0), station.GetInputPort("franka.desired_state"))
        builder.Connect(split.get_output_port(1), station.GetInputPort("allegro.desired_state"))
        # Search's target pixels: its camera's label image, rendered over the target's region only.
        pixels = task.pixels and TargetPixelCounter.from_sensor(
            station.GetSubsystemByName(f"camera_{next(iter(self.scenario.cameras))}"))
        assembler = builder.AddNamedSystem("observation", ObservationAssembler(self.plant, task.goal, pixels))
        for name in ("plant_state", "allegro.net_actuation") + (("query_object",) if pixels else ()):
            builder.Connect(station.GetOutputPort(name), assembler.GetInputPort(name))
        self._pixel_port = station.GetOutputPort("query_object") if pixels else None
        builder.Connect(split.get_output_port(2), assembler.GetInputPort("previous_action"))
        self.diagram = builder.Build()
        self.station, self.assembler = station, assembler
        self.simulator = Simulator(self.diagram)
        self.context = self.simulator.get_mutable_context()
        # Subsystem contexts of the (fixed) root context, looked up once: the per-step code writes and reads them.
        self._plant_context = self.plant.GetMyMutableContextFromRoot(self.context)
        self._station_context = station.GetMyContextFromRoot(self.context)
        self._assembler_context = assembler.GetMyMutableContextFromRoot(self.context)
        self._command_context = self._command_source.GetMyMutableContextFromRoot(self.context)
        self._hand_torque_port = station.GetOutputPort("allegro.net_actuation")
        self.objects = SceneObjects(station, self.scenario)
        self._controller_plant = MakeControllerPlant(self.scenario)
        self.ik = PalmIK(self._controller_plant, p_PalmC_Palm=p_PalmHc_Palm)
        self.arm = self.plant.GetModelInstanceByName("franka")
        self.hand = self.plant.GetModelInstanceByName("allegro")
        self.R_WP_home = self.ik.palm_pose(np.asarray(self.scenario.robot.arm_home)).rotation()
        self.R_WP_hold = self.R_WP_home  # The palm orientation the wrist holds (a reset may turn it for its episode).
        # A wrist-only task (``hand_actions=False``) pins the 16 hand dims to 0 (low == high): the hand is not the
        # policy's to move, and learners skip dims with no range (rl.networks.ActorCritic ``fixed_actions``).
        action_low = np.full(ACTION_SIZE, -1.0, np.float32)
        action_high = np.full(ACTION_SIZE, 1.0, np.float32)
        if not self.config.hand_actions:
            action_low[:16] = action_high[:16] = 0.0
        self.action_space = gym.spaces.Box(action_low, action_high, dtype=np.float32)
        size = assembler.size + (1 if self.config.observe_time else 0)  # The progress entry (observe_time).
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (size,), np.float32)
        self.target_object = ""
        self._object_body, self._p_OOcm = None, np.zeros(3)  # Of the target object (set_target).
        self.goal = np.array([0, 0, 0, 1.0, 0, 0, 0])
        self._steps = 0
        # The targets the command source holds, as lists of floats (the step's arithmetic; see ``step``).
        self._arm_target = floats(np.asarray(self.scenario.robot.arm_home, dtype=float))
        self._arm_velocity_target = [0.0] * 7
        self._hand_target = floats(ALLEGRO_OPEN_Q)
        self._previous_action = [0.0] * ACTION_SIZE
        self._scratch = None  # The plant context RefreshSampledOutputs computes into (allocated once).
        self._step_values = None  # The step's raw observation as floats while the step reads it back.
        self._step_memo = {}  # What the step's readers derived from it (raw_observation, object_position).
        self._observation_target = ObservationTarget()
        self.randomizer = DomainRandomizer(self, self.config.randomization)  # DR hook (envs/randomization.py)
        phases = self.config.phases
        self._phases = phases if phases is not None and phases.enabled else None
        # The base as made, and bound to the episode's target (set_target; tasks/residual.bind_base).
        self._unbound_base = self._residual_base = make_base(self.config.residual) if self.config.residual else None

    # ------------------------------------------------------------------------------------------- state
    @property
    def plant_context(self):
        return self._plant_context

    def arm_q(self) -> np.ndarray:
        return self.plant.GetPositions(self.plant_context, self.arm)

    def hand_q(self) -> np.ndarray:
        return self.plant.GetPositions(self.plant_context, self.hand)

    def object_body(self):
        return self._object_body

    def object_pose(self):
        return self.plant.EvalBodyPoseInWorld(self.plant_context, self._object_body)

    def object_position(self) -> np.ndarray:
        """World position of the target object's centre of mass (within a step, from the step's observation)."""
        if self._step_values is not None:
            return np.array(self._object_point())
        return self.object_pose().multiply(self._p_OOcm)

    def _object_point(self) -> list[float]:
        """:meth:`object_position` within a step, as floats (computed once a step)."""
        if "object_point" not in self._step_memo:
            self._step_memo["object_point"] = point_in_world(self._step_values[OBJECT_POSE],
                                                                    self._p_OOcm_values)
        return self._step_memo["object_point"]

    def hand_points(self) -> np.ndarray:
        """(5, 3) world positions of the four fingertips (index, middle, ring, thumb) and the palm centre, as
        ``SceneObjects.hand_points``, from the observation (within a step, the step's own)."""
        return np.array(self._hand_point_values(floats(self.raw_observation())))

    @staticmethod
    def _hand_point_values(observation: list[float]) -> list[list[float]]:
        """:meth:`hand_points` of an observation given as floats, as rows of floats."""
        tips = observation[FINGERTIPS]
        return [tips[k:k + 3] for k in range(0, 52, 13)] + [point_in_world(observation[PALM_POSE],
                                                                                   _P_PALM_CENTRE)]

    def fingertip_distance(self) -> float:
        """Sum of the four fingertips' distances to the target object's centre (the paper's Sigma f)."""
        if self._step_values is not None:
            observation, (cx, cy, cz) = self._step_values, self._object_point()
        else:
            observation, (cx, cy, cz) = floats(self.raw_observation()), floats(self.object_position())
        tips, total = observation[FINGERTIPS], 0.0  # Rows of 13; float arithmetic (4 x 3).
        for k in range(0, 52, 13):
            dx, dy, dz = tips[k] - cx, tips[k + 1] - cy, tips[k + 2] - cz
            total += math.sqrt(dx * dx + dy * dy + dz * dz)
        return total

    def hand_torque(self) -> np.ndarray:
        """The torques the 16 hand motors exert (within a step, the step's observation's motor tactile)."""
        if self._step_values is not None:
            return np.array(self._step_values[MOTOR_TACTILE])
        return self._hand_torque_port.Eval(self._station_context)

    def set_robot(self, arm_q: np.ndarray, hand_q: np.ndarray) -> None:
        """Places the robot at rest at these positions and holds them as PD targets."""
        self.plant.SetPositions(self.plant_context, self.arm, arm_q)
        self.plant.SetPositions(self.plant_context, self.hand, hand_q)
        self.plant.SetVelocities(self.plant_context, self.arm, np.zeros(7))
        self.plant.SetVelocities(self.plant_context, self.hand, np.zeros(16))
        self._hand_target = floats(np.asarray(hand_q, dtype=float))
        self._set_sources(floats(np.asarray(arm_q, dtype=float)), self._hand_target, [0.0] * ACTION_SIZE)

    def hover_arm(self, p_WT: np.ndarray) -> np.ndarray:
        """Arm positions placing the hand centre ``hover_height`` above target point ``p_WT``, palm down."""
        q, error = self.ik.solve(np.asarray(self.scenario.robot.arm_home), np.asarray(p_WT) +
                                 [0, 0, self.config.hover_height], self.R_WP_hold)
        if error > 0.01:
            raise RuntimeError(f"the hover pose above {np.round(p_WT, 3)} is out of reach ({error:.3f} m)")
        return q

    def set_target(self, name: str, goal: np.ndarray | None = None) -> None:
        """Declares the episode's target object (and goal pose [xyz, wxyz]) for observations and rewards."""
        self.target_object = name
        self._object_body = self.objects.bodies[self.objects.index(name)]
        self._p_OOcm = self._object_body.default_com()
        self._p_OOcm_values = floats(self._p_OOcm)
        if goal is not None:
            self.goal = np.asarray(goal, dtype=float)
        label = int(self.object_body().index())  # MultibodyPlant labels each body's geometry by body index.
        self._observation_target = ObservationTarget(object_body=label, goal=self.goal, label=label)
        self.assembler.set_target(self._assembler_context, self._observation_target)
        self._residual_base = bind_base(self._unbound_base, name)

    def get_state(self) -> EnvState:
        return scene_handoff.capture(self, EnvState(
            self.plant.GetPositions(self.plant_context).copy(), self.plant.GetVelocities(self.plant_context).copy(),
            self.objects.get_state(self.context), self.target_object, self.goal.copy(), np.array(self._arm_target),
            np.array(self._hand_target), np.array(self._previous_action), self.config.name,
            np.array(self._arm_velocity_target), float(self.context.get_time())))

    def set_state(self, state: EnvState) -> None:
        """Restores a saved state exactly (a few state writes and one contact solve for the sampled outputs; no
        re-simulation), its simulation time included. A state saved on another station scene (another plant size:
        a hand-off between sub-tasks of different scenes) carries over the robot and the target object, the rest
        of this scene parked (``envs/scene_handoff.py``)."""
        if np.size(state.plant_positions) != self.plant.num_positions():
            scene_handoff.restore(self, state)
        else:
            self.context.SetTime(float(state.time))
            self.plant.SetPositions(self.plant_context, state.plant_positions)
            self.plant.SetVelocities(self.plant_context, state.plant_velocities)
            self.objects.set_state(self.context, state.objects)
            self.set_target(state.target_object, state.goal)
        arm, hand, previous, arm_v = (floats(np.asarray(v, dtype=float)) for v in (
            state.arm_target, state.hand_target, state.previous_action, state.arm_velocity_target))
        self._hand_target = hand
        self._set_sources(arm, hand, previous, arm_v)
        self.refresh_sampled_outputs()

    def refresh_sampled_outputs(self) -> None:
        """Recomputes the plant's sampled outputs (motor tactile, contacts) for the current state and targets,
        as the next step would: call after editing the state without a step (reset and restore do)."""
        self._scratch = RefreshSampledOutputs(self.plant, self.plant_context, self._scratch)

    def _set_sources(self, arm_q: list[float], hand_q: list[float], previous_action: list[float],
                     arm_v: list[float] | None = None) -> None:
        """Writes the command source: the arm's and the hand's desired states [q, v] (the hand's v is 0) and the
        previous action, each a list of floats (as the env keeps them)."""
        command = arm_q + (_ZEROS_7 if arm_v is None else arm_v) + hand_q + _ZEROS_16 + previous_action
        if len(command) != COMMAND_SIZE:
            raise ValueError(f"the env's command must have {COMMAND_SIZE} entries, got {len(command)}")
        self._command_source.get_mutable_source_value(self._command_context).SetFromVector(np.array(command))
        self._arm_target, self._arm_velocity_target = command[:7], command[7:14]
        self._previous_action = command[46:]

    def observation_values(self) -> list[float]:
        """:meth:`raw_observation` as a list of floats, for float arithmetic on a few entries. Within a step the
        step's own list (read it, do not modify it)."""
        if self._step_values is not None:
            return self._step_values
        return self.raw_observation().tolist()

    def raw_observation(self) -> np.ndarray:
        """The assembled observation (float64, before any observation noise).

        Outside a step: the observation port's value (Drake caches it until the state changes). Inside a step,
        where the tasks' rewards and success tests and the wake check read it: the step's own observation,
        assembled once (read-only)."""
        if self._step_values is not None:
            if "raw_observation" not in self._step_memo:
                raw = np.array(self._step_values)
                raw.flags.writeable = False
                self._step_memo["raw_observation"] = raw
            return self._step_memo["raw_observation"]
        return self.assembler.get_output_port().Eval(self._assembler_context)

    def _assemble_values(self, plant_state: list[float] | None = None) -> list[float]:
        """The observation port's value as floats, computed from the values the port's inputs carry (the same
        numbers, without copying them into the assembler's context). ``plant_state``: the plant's [q, v] as
        floats, if at hand."""
        if plant_state is None:
            plant_state = self.plant.GetPositionsAndVelocities(self._plant_context).tolist()
        pixel_input = None if self._pixel_port is None else self._pixel_port.Eval(self._station_context)
        return self.assembler.assemble_values(plant_state, self._observation_target, self._previous_action,
                                              self._hand_torque_port.Eval(self._station_context), pixel_input)

    def observation(self) -> np.ndarray:
        """The policy's observation: :meth:`raw_observation` in float32, with the episode's progress appended
        when ``TaskConfig.observe_time``."""
        return self._with_time(self.raw_observation().astype(np.float32))

    def _with_time(self, observation: np.ndarray) -> np.ndarray:
        if not self.config.observe_time:
            return observation
        return np.append(observation, np.float32(self._steps / self.config.episode_length))

    # ------------------------------------------------------------------------------------------ gym API
    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        # A full reset, from what a new env holds (nominal model on a seeded reset): same seed and actions, same
        # trajectory, whatever the env did before (tests/test_reset_determinism.py).
        self.context.SetTime(0.0)
        self.plant.SetDefaultState(self._plant_context, self._plant_context.get_mutable_state())
        self.set_robot(np.asarray(self.scenario.robot.arm_home, dtype=float), ALLEGRO_OPEN_Q)
        self.goal = np.array([0, 0, 0, 1.0, 0, 0, 0])
        self.R_WP_hold = self.R_WP_home
        self.objects.forget_motion()
        if seed is not None:
            self.randomizer.restore_nominal()
        self.simulator.Initialize()  # Some resets simulate (Insert's scripted hand-off).
        initial_state = (options or {}).get("initial_state")
        if initial_state is not None:
            if not isinstance(initial_state, EnvState):
                raise TypeError("options['initial_state'] must be an EnvState (env.get_state() or a buffer)")
            self.set_state(initial_state)
            self.task.on_restore(self, initial_state.task)
        else:
            self.task.reset(self, self.np_random)
        # DR hook: physical parameters, pose noise, correlated noise (no-op with every group off).
        self.randomizer.on_reset(self.np_random, reseed=seed is not None, task_reset=initial_state is None)
        self.simulator.Initialize()
        self.refresh_sampled_outputs()
        self._steps = 0
        return self.randomizer.perturb_observation(self.observation()), {"success": bool(self.task.is_success(self))}

    def step(self, action):
        # The step's arithmetic is on Python floats and lists, with a handful of Drake and numpy calls: right
        # after the physics, this code runs with its caches cold, where every distinct numpy function costs
        # microseconds (see docs/performance.md, "How the env time is spent").
        action = np.asarray(action, dtype=float)
        if action.shape != (ACTION_SIZE,):
            raise ValueError(f"action must have shape ({ACTION_SIZE},), got {action.shape}")
        a = action.tolist()
        if not all(map(math.isfinite, a)):
            return self.observation(), 0.0, False, True, {"nan_action": True, "success": False}
        if self._residual_base is not None:  # A residual policy: the action corrects a script (tasks/residual.py).
            a = apply_residual(self._residual_base, self.observation(), self._steps, a)
        randomizer = self.randomizer if self.randomizer.enabled else None  # DR hooks only if any group is on.
        if randomizer is not None:
            a = randomizer.perturb_action(a)  # DR hook: action noise
        a = [min(max(x, -1.0), 1.0) for x in a]
        hand_frozen = False
        if self._phases is not None:  # The release's scripted lift and frozen hand (tasks/phases.py).
            a, hand_frozen = apply_phases(self._phases, self._steps, a, self._previous_action)
        if hand_frozen:
            pass  # The hand holds its targets; ``a`` carries the previous step's hand entries.
        elif self.config.hand_actions or self._residual_base is not None:  # Joint targets scaled to the limits
            # (allegro.scale_action_to_limits); with a residual base, the base's hand plus the policy's correction.
            target = [low + 0.5 * (x + 1.0) * r for x, low, r in zip(a[:16], _HAND_LOW, _HAND_RANGE, strict=True)]
            ema = self.config.ema
            self._hand_target = target if ema == 1.0 else [ema * t + (1 - ema) * h
                                                           for t, h in zip(target, self._hand_target, strict=True)]
        else:
            a[:16] = _ZEROS_16  # Ignored; zeroed so the previous-action observation does not carry them.
        # Integrate the wrist command from the previous *target*, not the measured arm: with a payload the
        # PD controller sags a little, and re-targeting from the measurement would turn that sag into drift.
        (cx, cy, cz), step = self.ik.palm_point(self._arm_target), self.config.wrist_step
        p_WC = [cx + step * a[16], cy + step * a[17], max(cz + step * a[18], self.config.wrist_floor)]
        arm_target = self.ik.step_values(self._arm_target, p_WC, self.R_WP_hold)
        # The target moves at (arm_target - previous target) / period: feed that velocity forward, or the arm's
        # heavily damped PD (kd / kp = 0.2 s) would trail a moving wrist command by centimetres.
        period = self.scenario.control_period
        arm_v = [(q - q_last) / period for q, q_last in zip(arm_target, self._arm_target, strict=True)]
        self._set_sources(arm_target, self._hand_target, a, arm_v)
        info = {"nan_action": False, "simulator_error": False}
        try:
            self.simulator.AdvanceTo(self.context.get_time() + period)
            x = self.plant.GetPositionsAndVelocities(self._plant_context).tolist()
            values = self._assemble_values(x)
        except RuntimeError as error:  # A failed contact solve, NaN state, ...: a truncation.
            info.update(simulator_error=True, error=str(error), success=False)
            return np.zeros(self.observation_space.shape, np.float32), 0.0, False, True, info
        observation = np.array(values, dtype=np.float32)
        # All finite (in float32) unless the sum of magnitudes says otherwise; then numpy decides exactly.
        if not sum(map(abs, values)) < _FLOAT32_MAX and not np.isfinite(observation).all():
            info.update(simulator_error=True, error="non-finite observation", success=False)
            observation = self._with_time(np.nan_to_num(observation, nan=0.0, posinf=0.0, neginf=0.0))
            return observation, 0.0, False, True, info
        self._steps += 1
        observation = self._with_time(observation)
        self._step_values = values  # What the readers below see (raw_observation() etc.) until the step ends.
        try:
            terms = self.task.reward_terms(self, np.array(a))  # The action as applied (noised, clipped).
            info.update({_reward_key(k): v for k, v in terms.items()})
            info["success"] = bool(self.task.is_success(self))
            terminated = bool(self.task.is_failure(self))
            # Last, as it moves nothing the observation, reward or success test shows (a freeze edits collision
            # filters and masses only).
            self.objects.update(self.context, self._hand_point_values(values), x)
        finally:
            self._step_values, self._step_memo = None, {}
        truncated = self._steps >= self.config.episode_length
        if randomizer is not None:
            randomizer.on_step()  # DR hook: re-applies object masses, re-draws every N plant steps
            observation = randomizer.perturb_observation(observation)  # DR hook: observation noise
        return observation, float(sum(terms.values())), terminated, truncated, info


def make_env(name: str, config: TaskConfig | None = None, meshcat=None) -> SubtaskEnv:
    """A :class:`SubtaskEnv` for sub-task ``name`` with ``config`` (default: its ``default_config()``), shown in
    ``meshcat`` if given."""
    return SubtaskEnv(make_task(name, config), meshcat=meshcat)
