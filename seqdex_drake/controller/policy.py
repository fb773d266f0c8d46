"""A trained sub-policy as a Drake LeafSystem: observation in, filtered 60 Hz hand and wrist commands out.

:class:`PolicySystem` hosts one :class:`~seqdex_drake.rl.networks.ActorCritic` (observation normalizer inside)
and runs its deterministic action (the Gaussian's mean) once per control period. The 19-dim action is
clipped to [-1, 1]; its 16 hand entries are low-pass filtered with an exponential moving average,
``filtered = ema * new + (1 - ema) * previous`` (the paper's deployment value is ``ema = 0.2``,
:data:`DEPLOYMENT_EMA`; the sub-task environments train with each task's ``TaskConfig.ema``). Because
:func:`~seqdex_drake.robots.allegro.scale_action_to_limits` is affine on [-1, 1], filtering the action is
filtering the joint targets, exactly as the environments do. The 3 wrist entries are not filtered unless
``smooth_wrist`` (the environments do not filter them).

Chaining. Several PolicySystems share one robot, so the filter's memory is the action the robot *applies*,
not the system's own last output: connect ``previous_action`` (raw) and ``previous_filtered_action`` to the
applied action (the chain's router does). A system whose ``active`` input is 0 skips inference and copies
the applied action into its state, so that whenever it is routed to the robot its outputs are what the robot
executes; when it becomes active its first filtered action starts from the applied one.

Scripted stages. :meth:`PolicySystem.scripted` hosts no network: the stage's scripted base (``params.residual``,
``tasks/residual.py``) acts alone, as a scripted task's env applies it (``Task.scripted``, e.g. the Building Blocks
retrieve). A base bound to the chain's target (its ``for_object``: the retrieve needs the block's length) is bound
from the ``target_body`` parameter (:meth:`PolicySystem.set_target_body`, which ``SetChainTarget`` calls) and the
station plant's object names by body index. Output ``finished`` is 1 from the tick after the base says its work is over.

Inference. By default (``PolicyParams.inference = "numpy"``) the action mean comes from a
:class:`~seqdex_drake.controller.inference.PolicySnapshot`: the actor and its normalizer copied into float32 numpy
arrays, equal to the torch model's output to ~1e-6 relative and several times cheaper per batch-1 call (torch's
per-operator dispatch dominated). The snapshot is rebuilt when the model's tensors change in place.
``inference = "torch"`` runs the model itself.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import torch
from pydrake.systems.framework import BasicVector, Context, DiscreteValues, LeafSystem

from seqdex_drake.controller.inference import PolicySnapshot
from seqdex_drake.rl.checkpoint import capture_rng_state, restore_rng_state
from seqdex_drake.rl.networks import ActorCritic
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q, scale_action_to_limits, unscale_limits_to_action
from seqdex_drake.tasks.phases import ScriptedPhases, apply_phases
from seqdex_drake.tasks.residual import apply_residual, base_finished, bind_base, make_base

ACTION_SIZE = 19
HAND_SIZE = 16
DEPLOYMENT_EMA = 0.2
"""The paper's EMA factor for real-world deployment (appendix, "Real-world setup")."""
PAPER_HIDDEN_SIZES = (1024, 1024, 512)
"""Actor hidden sizes of the paper's PPO tables (used for untrained policies)."""
_HAND_Q = slice(7, 23)
"""Allegro joint positions in every observation layout (``observation_layout.py``, indices 7-22)."""


@dataclasses.dataclass
class PolicyParams:
    """Parameters of :class:`PolicySystem`."""

    control_period: float = 1.0 / 60.0
    """Seconds between policy updates (the scenario's ``control_period``; the paper runs at 60 Hz)."""
    ema: float = DEPLOYMENT_EMA
    """EMA factor a of the hand action: ``filtered = a * new + (1 - a) * previous``; 1 disables filtering."""
    smooth_wrist: bool = False
    """Also filter the 3 wrist entries (the environments do not)."""
    wrist_step: float = 0.005
    """Wrist (hand centre) translation per update at action 1 (m), ``TaskConfig.wrist_step``."""
    inference: str = "numpy"
    """"numpy": a float32 numpy snapshot of the actor (fast at batch 1); "torch": the torch model itself."""
    time_steps: int = 0
    """The episode length of a policy trained with ``TaskConfig.observe_time``: its input is the stage's
    observation plus ``ticks / time_steps`` (ticks since it became active), as the env appends its progress;
    0: the observation alone."""
    phases: ScriptedPhases | None = None
    """The scripted phases the policy was trained with (``TaskConfig.phases``, e.g. tool Grasp's scripted lift),
    applied to its action on the count of ticks since it became active, as the env applies them on its step
    count; None: none."""
    residual: str = ""
    """The scripted base a residual policy was trained on (``TaskConfig.residual``, ``tasks/residual.py``): the
    system applies ``clip(base(observation, ticks) + policy action)``, as the env does; "": none."""


def _check_model(model: ActorCritic, observation_size: int, source: str) -> None:
    if model.obs_dim != observation_size:
        raise ValueError(f"policy {source} reads {model.obs_dim}-dim observations, but its stage's observation "
                         f"has {observation_size} (expected {observation_size}, found {model.obs_dim}); use the "
                         f"checkpoint trained for this stage's task")
    if model.action_dim != ACTION_SIZE:
        raise ValueError(f"policy {source} outputs {model.action_dim} actions; the station needs {ACTION_SIZE} "
                         f"(16 hand joints + 3 wrist translation)")


class PolicySystem(LeafSystem):
    """Runs one sub-policy at the control rate and holds its filtered action (a zero-order hold).

    Input ports: ``observation`` (the stage's observation size), ``active`` (1, optional: unconnected means
    always active), ``previous_action`` (19, optional: the raw action the robot applied last tick),
    ``previous_filtered_action`` (19, optional: the filtered action the robot applies now). Unconnected
    feedback inputs mean "this system's own last output".

    Output ports (all held between updates, no direct feedthrough): ``action`` (19, clipped to [-1, 1],
    hand part EMA-filtered), ``raw_action`` (19, clipped, unfiltered: what the observations' previous-action
    entries hold), ``hand_target`` (16 Allegro joint targets, rad), ``wrist_translation`` (3, m), ``finished``
    (1: the system is active and its base said at its last update that its work is over; 0 otherwise, so a stage
    that has just handed over does not end the next one).

    Parameter: ``target_body`` (1, the chain target's body index in the station plant; -1: none), which binds a
    target-dependent base (:meth:`set_target_body`).

    At initialization the filter memory becomes the action that holds the measured hand joint positions
    (read from the observation) and a zero wrist motion, so starting a simulation does not jerk the hand.

    Construct with :meth:`from_checkpoint`, :meth:`untrained`, :meth:`scripted`, or directly from an in-memory model.

    Args:
        model: the actor-critic; it is put in eval mode and used for inference only. None: a scripted stage
            (``params.residual`` names its base; :meth:`scripted`).
        observation_size: size of the stage's observation (checked against the model's input).
        params: update period, EMA factor, wrist step; defaults to ``PolicyParams()``.
        trained: False marks a freshly initialised policy (the chain runs without checkpoints).
        source: where the model came from (a file path or a description), used in messages.
    """

    def __init__(self, model: ActorCritic | None, observation_size: int, params: PolicyParams | None = None,
                 trained: bool = True, source: str = "in-memory model", body_names: list[str] | None = None):
        super().__init__()
        self._params = params = params or PolicyParams()
        if not 0.0 < params.ema <= 1.0:
            raise ValueError(f"the EMA factor must be in (0, 1], got {params.ema}")
        if params.control_period <= 0:
            raise ValueError(f"control_period must be positive, got {params.control_period}")
        if params.inference not in ("numpy", "torch"):
            raise ValueError(f"inference must be 'numpy' or 'torch', got {params.inference!r}")
        if params.time_steps < 0:
            raise ValueError(f"time_steps must be >= 0, got {params.time_steps}")
        if model is None and not params.residual:
            raise ValueError(f"{source}: a scripted stage (no model) needs its base, PolicyParams.residual")
        if model is not None:
            _check_model(model, observation_size + (1 if params.time_steps else 0), source)
        self._residual_base = make_base(params.residual) if params.residual else None
        self._bound: dict[int, object] = {}  # Target body index -> the base bound to it (a pure function's cache).
        self._body_names = list(body_names or [])
        self.model = model.eval() if model is not None else None
        self.is_scripted = model is None  # A scripted stage (see scripted()).
        self._snapshot = PolicySnapshot(model) if params.inference == "numpy" and model is not None else None
        self.trained = bool(trained)
        self.source = str(source)
        self.observation_size = int(observation_size)
        self._weight = np.full(ACTION_SIZE, float(params.ema))
        if not params.smooth_wrist:
            self._weight[HAND_SIZE:] = 1.0

        self._observation_port = self.DeclareVectorInputPort("observation", observation_size)
        self._active_port = self.DeclareVectorInputPort("active", 1)
        self._previous_port = self.DeclareVectorInputPort("previous_action", ACTION_SIZE)
        self._previous_filtered_port = self.DeclareVectorInputPort("previous_filtered_action", ACTION_SIZE)
        initial = np.r_[unscale_limits_to_action(ALLEGRO_OPEN_Q), np.zeros(3)]
        # State: [filtered action (19), raw action (19)], and the ticks since the system became active.
        self._state_index = self.DeclareDiscreteState(np.r_[initial, initial])
        self._ticks_index = self.DeclareDiscreteState(1)
        self._finished_index = self.DeclareDiscreteState(1)
        self._target_index = self.DeclareNumericParameter(BasicVector([-1.0]))
        ticket = {self.discrete_state_ticket(self._state_index)}
        self.DeclareVectorOutputPort("action", ACTION_SIZE, self._calc_action, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("raw_action", ACTION_SIZE, self._calc_raw, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("hand_target", HAND_SIZE, self._calc_hand, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("wrist_translation", 3, self._calc_wrist, prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("finished", 1, self._calc_finished, prerequisites_of_calc={
            self.discrete_state_ticket(self._finished_index), self.input_port_ticket(self._active_port.get_index())})
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(params.control_period, 0.0, self._update)

    # ------------------------------------------------------------------------------------- constructors
    @classmethod
    def from_checkpoint(cls, path: str | os.PathLike, observation_size: int,
                        params: PolicyParams | None = None) -> PolicySystem:
        """Loads the model of a PPO checkpoint (``last.pt`` / ``best.pt``) with ``PPO.resume``.

        Loading restores the caller's random-number generator states afterwards (``PPO.resume`` reseeds them).

        Raises:
            FileNotFoundError: no such file.
            ValueError: the checkpoint's observation size differs from ``observation_size`` (names the file and
                both sizes), or its action size is not 19.
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"policy checkpoint {path} does not exist; train the stage first "
                                    f"(seqdex train --task <task> --run-dir ...) or pass None for an untrained policy")
        rng_state = capture_rng_state()
        try:
            ppo = PPO.resume(path, device="cpu")
        finally:
            restore_rng_state(rng_state)
        return cls(ppo.model, observation_size, params, trained=True, source=str(path))

    @classmethod
    def untrained(cls, observation_size: int, seed: int = 0, params: PolicyParams | None = None,
                  hidden_sizes: tuple[int, ...] = PAPER_HIDDEN_SIZES) -> PolicySystem:
        """A freshly initialised policy (``trained = False``), seeded without touching the global torch RNG.

        Its actions are near zero (the output layer starts at gain 0.01): the hand moves to the middle of its
        joint ranges and the wrist stays put.
        """
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            inputs = observation_size + (1 if params is not None and params.time_steps else 0)
            model = ActorCritic(inputs, ACTION_SIZE, hidden_sizes, critic_hidden_sizes=(8,))
        return cls(model, observation_size, params, trained=False, source=f"untrained policy (seed {seed})")

    @classmethod
    def scripted(cls, observation_size: int, params: PolicyParams, body_names: list[str] | None = None
                 ) -> PolicySystem:
        """A scripted stage: ``params.residual``'s base acts alone (no network). ``body_names``: the station plant's
        object (model instance) name of each body, by body index, to bind a target-dependent base
        (:meth:`set_target_body`)."""
        return cls(None, observation_size, params, trained=True, source=f"the scripted {params.residual}",
                   body_names=body_names)

    # ------------------------------------------------------------------------------------------ helpers
    def set_target_body(self, context: Context, body_index: int) -> None:
        """Sets the chain target's body index (station plant) in this system's ``context``: a base with a
        ``for_object`` hook acts on that body's name. Raises a ValueError for an index the plant lacks."""
        if self._body_names and not 0 <= int(body_index) < len(self._body_names):
            raise ValueError(f"body index {body_index} is not a body of the station plant "
                             f"(0..{len(self._body_names) - 1})")
        context.get_mutable_numeric_parameter(self._target_index).SetFromVector([float(body_index)])

    def ticks(self, context: Context) -> int:
        """Control ticks this stage has acted since it last became active (the step its scripted base sees)."""
        return int(context.get_discrete_state(self._ticks_index).get_value()[0])

    def scripted_base(self, context: Context):
        """The scripted base (residual or scripted stage) bound to the current target; None for a pure network."""
        return None if self._residual_base is None else self._base(context)

    def _base(self, context: Context):
        """The residual base bound to the target (unbound when no target is set or no body names are known)."""
        index = int(context.get_numeric_parameter(self._target_index).GetAtIndex(0))
        if index < 0 or not self._body_names:
            return self._residual_base
        if index not in self._bound:
            self._bound[index] = bind_base(self._residual_base, self._body_names[index])
        return self._bound[index]

    @property
    def params(self) -> PolicyParams:
        return self._params

    def raw_action(self, observation: np.ndarray) -> np.ndarray:
        """The clipped deterministic action for one observation (no filtering), by ``params.inference``; zeros
        for a scripted stage (its base is the whole action)."""
        if self.model is None:
            return np.zeros(ACTION_SIZE)
        if self._snapshot is None:
            return self.torch_raw_action(observation)
        if self._snapshot.stale():  # The model's weights changed in place since the snapshot.
            self._snapshot = PolicySnapshot(self.model)
        action = self._snapshot(np.asarray(observation, dtype=np.float32).reshape(-1)).astype(float)
        return np.clip(action, -1.0, 1.0, out=action)

    def torch_raw_action(self, observation: np.ndarray) -> np.ndarray:
        """:meth:`raw_action` through the torch model (the reference the numpy snapshot is tested against)."""
        with torch.inference_mode():
            obs = torch.as_tensor(np.asarray(observation, dtype=np.float32)).reshape(1, -1)
            action = self.model.action_mean(obs)[0].numpy().astype(float)
        return np.clip(action, -1.0, 1.0)

    def filter(self, raw: np.ndarray, previous_filtered: np.ndarray) -> np.ndarray:
        """The EMA step: ``ema * raw + (1 - ema) * previous`` on the hand (and wrist if smoothed), clipped."""
        return np.clip(self._weight * raw + (1.0 - self._weight) * previous_filtered, -1.0, 1.0)

    # ------------------------------------------------------------------------------------------- events
    def _memory(self, context: Context) -> tuple[np.ndarray, np.ndarray]:
        """(filtered, raw) action the robot applies: the feedback inputs if connected, else own state."""
        state = context.get_discrete_state(self._state_index).get_value()
        filtered = (self._previous_filtered_port.Eval(context) if self._previous_filtered_port.HasValue(context)
                    else state[:ACTION_SIZE])
        raw = self._previous_port.Eval(context) if self._previous_port.HasValue(context) else state[ACTION_SIZE:]
        return np.asarray(filtered, dtype=float), np.asarray(raw, dtype=float)

    def _initialize(self, context: Context, discrete_state: DiscreteValues) -> None:
        observation = self._observation_port.Eval(context)
        hold = np.r_[np.clip(unscale_limits_to_action(observation[_HAND_Q]), -1.0, 1.0), np.zeros(3)]
        discrete_state.set_value(self._state_index, np.r_[hold, hold])
        discrete_state.set_value(self._ticks_index, [0])
        discrete_state.set_value(self._finished_index, [0.0])

    def _update(self, context: Context, discrete_state: DiscreteValues) -> None:
        filtered, raw = self._memory(context)
        active = not self._active_port.HasValue(context) or self._active_port.Eval(context)[0] > 0.5
        ticks = self.ticks(context)
        finished = False
        if active:
            observation = self._observation_port.Eval(context)
            if self._params.time_steps:  # A time-aware policy (TaskConfig.observe_time): its progress appended.
                observation = np.append(observation, ticks / self._params.time_steps)
            action = self.raw_action(observation)
            if not np.all(np.isfinite(action)):
                raise RuntimeError(f"policy {self.source} produced a non-finite action at t = "
                                   f"{context.get_time():.3f} s (non-finite observation or weights)")
            if self._residual_base is not None:  # As the env: the policy corrects its scripted base.
                base = self._base(context)
                action = np.array(apply_residual(base, observation, ticks, action.tolist()))
                finished = base_finished(base, observation, ticks)
            if self._params.phases is not None:  # As the env: the scripted lift, the frozen hand.
                action = np.array(apply_phases(self._params.phases, ticks, action.tolist(), raw.tolist())[0])
            raw, filtered = action, self.filter(action, filtered)
        discrete_state.set_value(self._state_index, np.concatenate((filtered, raw)))
        discrete_state.set_value(self._ticks_index, [ticks + 1 if active else 0])
        discrete_state.set_value(self._finished_index, [float(finished)])

    def _state(self, context: Context) -> np.ndarray:
        return context.get_discrete_state(self._state_index).get_value()

    def _calc_action(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self._state(context)[:ACTION_SIZE])

    def _calc_raw(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self._state(context)[ACTION_SIZE:])

    def _calc_hand(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(scale_action_to_limits(self._state(context)[:HAND_SIZE]))

    def _calc_finished(self, context: Context, output: BasicVector) -> None:
        active = not self._active_port.HasValue(context) or self._active_port.Eval(context)[0] > 0.5
        output.SetFromVector(context.get_discrete_state(self._finished_index).get_value() * float(active))

    def _calc_wrist(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self._state(context)[HAND_SIZE:ACTION_SIZE] * self._params.wrist_step)
