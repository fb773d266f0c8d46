"""What every sub-task shares: its config dataclass and the hooks the environment calls.

A sub-task module (``tasks/<name>.py``) starts with ``default_config()`` returning a :class:`TaskConfig`
and defines a :class:`Task` subclass; ``tasks/registry.py`` maps names to them.
"""

import abc
import dataclasses

import numpy as np

from seqdex_drake.scenario import LoadScenario
from seqdex_drake.tasks.phases import ScriptedPhases
from seqdex_drake.tasks.randomization_config import RandomizationConfig
from seqdex_drake.tasks.residual import RESIDUAL_BASES
from seqdex_drake.tasks.rewards import RewardWeights


class ResetError(ValueError):
    """A reset the task cannot make with its config (e.g. an object its scripted start cannot hold); the message
    names the object and what to do instead."""


@dataclasses.dataclass
class TaskConfig:
    """Configuration of one sub-task MDP (paper appendix and FACTS.md)."""

    name: str = ""
    """Registry name of the sub-task."""
    scenario: str = ""
    """Station scenario, ``family/name``."""
    episode_length: int = 150
    """Policy steps per episode (60 Hz); reaching it is a truncation."""
    ema: float = 1.0
    """EMA factor of the hand joint targets: target = ema * new + (1 - ema) * previous (1 = no smoothing)."""
    hand_actions: bool = True
    """False: the policy's 16 hand entries are pinned to 0 (a wrist-only action space). Without a ``residual`` base
    the hand then holds its targets (the hand-over chain's tasks); with one, the base's hand actions apply
    uncorrected (the policy corrects the wrist only)."""
    wrist_floor: float = 0.0
    """Lowest world height (m) the wrist command may take the hand centre to (a workspace limit; 0: none)."""
    wrist_step: float = 0.005
    """Wrist (hand centre) translation per policy step at action 1 (m); 0.3 m/s at 60 Hz."""
    reward: RewardWeights = dataclasses.field(default_factory=RewardWeights)
    """The paper's lambda / alpha / e0 values for this sub-task."""
    object_types: list[int] = dataclasses.field(default_factory=lambda: [1, 2, 3, 4, 5])
    """Object variants sampled at reset (block types 1-5 train, 6-8 unseen; tools by index)."""
    reset_region: str = "box"
    """Where a single-block reset puts its block (Orient, Grasp): "box" (the storage box, where they train) or
    "staging" (the clear table area where a block taken out of the pile is set down;
    ``tasks/blocks_common.STAGING_LOW``). Other tasks ignore it."""
    hover_height: float = 0.05
    """The hand centre starts this far above the target (the paper's OSC hand-over point)."""
    success_threshold: list[float] = dataclasses.field(default_factory=list)
    """Task-specific success thresholds (documented by each task's default_config)."""
    drop_height: float = 0.45
    """An object whose centre falls below this height (m) has left the table: task failure (terminated)."""
    randomization: RandomizationConfig = dataclasses.field(default_factory=RandomizationConfig)
    """Domain randomization (``envs/randomization.py``). Default: every group off, so resets and rewards are
    exactly reproducible; train with ``RandomizationConfig.paper()`` (the paper's table, all on)."""
    observe_time: bool = False
    """Append the episode's progress, ``step / episode_length`` (0 at reset), to the observation. A policy whose
    episode has time-based scripted phases (``phases``) needs it: without it, when the scripted lift comes is
    not in its state (a time-aware observation, as Pardo et al. 2018 recommend for time limits)."""
    phases: ScriptedPhases | None = None
    """Scripted phases of the episode as the release has them (``tasks/phases.py``: a scripted lift, a frozen
    hand); None: the policy acts every step (the paper's MDP)."""
    scenario_overrides: str = ""
    """YAML applied on top of ``scenario`` (``LoadScenario``'s ``scenario_text``), e.g. ``"{plant_config:
    {time_step: 0.002}}"`` to train or measure a sub-task under other physics settings; "": the scenario as it is."""
    residual: str = ""
    """A scripted base controller (``tasks/residual.py``, e.g. ``"tool_grasp_script"``) that the policy's action
    corrects: the env applies ``clip(base(observation, step) + action)``; "": the action itself (the paper's)."""
    goal_yaws_deg: list[float] = dataclasses.field(default_factory=lambda: [0.0, 90.0])
    """Goal-pose yaws [deg] a goal task draws from at reset, each a multiple of 90 (the plate's stud grid; Insert:
    0 puts the block's long side along world x, 90 along y). Default: both, as the paper."""

    def load_scenario(self):
        """The station scenario this sub-task runs in: ``scenario`` with ``scenario_overrides`` applied."""
        return LoadScenario(self.scenario, scenario_text=self.scenario_overrides or "{}")

    def __post_init__(self):
        """Refuses values no episode can run with (``ValueError`` naming the field, the value and the range)."""
        where = f"TaskConfig {self.name}" if self.name else "TaskConfig"

        def require(ok: bool, field: str, expected: str) -> None:
            if not ok:
                raise ValueError(f"{where}: {field} must be {expected}, got {getattr(self, field)!r}")

        def number(value) -> bool:
            return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)

        def finite(value) -> bool:
            return number(value) and bool(np.isfinite(value))

        def integer(value) -> bool:
            return isinstance(value, int | np.integer) and not isinstance(value, bool)

        require(integer(self.episode_length) and self.episode_length >= 1, "episode_length", "an integer >= 1")
        require(finite(self.ema) and 0.0 < self.ema <= 1.0, "ema", "in (0, 1] (1: no smoothing)")
        require(finite(self.wrist_step) and self.wrist_step > 0.0, "wrist_step", "a finite length > 0 (m)")
        require(finite(self.wrist_floor), "wrist_floor", "a finite height (m; 0: none)")
        require(finite(self.hover_height) and self.hover_height >= 0.0, "hover_height", "a finite height >= 0 (m)")
        require(finite(self.drop_height), "drop_height", "a finite height (m)")
        require(len(self.object_types) > 0 and all(integer(t) for t in self.object_types), "object_types",
                "a non-empty list of integer object variants")
        require(all(finite(t) for t in self.success_threshold), "success_threshold", "a list of finite numbers")

        require(self.reset_region in ("box", "staging"), "reset_region", "'box' or 'staging'")
        require(self.residual == "" or self.residual in RESIDUAL_BASES, "residual",
                f"'' or one of {', '.join(RESIDUAL_BASES)}")
        require(len(self.goal_yaws_deg) > 0 and all(finite(yaw) and float(yaw) % 90.0 == 0.0
                                                    for yaw in self.goal_yaws_deg),
                "goal_yaws_deg", "a non-empty list of multiples of 90 (deg)")


class Task(abc.ABC):
    """Hooks of one sub-task; the environment owns the simulation and calls these.

    Subclasses set ``goal`` / ``pixels`` (extra observation parts) and implement the methods below.
    """

    goal: bool = False
    pixels: bool = False
    scripted: bool = False
    """A scripted stage: its config's ``residual`` base acts alone (no policy is trained or shipped for it), and in
    a chain it ends when the base says it is finished (``tasks/residual.base_finished``) or at its step budget."""

    def __init__(self, config: TaskConfig):
        self.config = config

    @abc.abstractmethod
    def reset(self, env, rng: np.random.Generator) -> None:
        """Samples the episode's initial state from the scenario's distribution (objects, arm, hand, target)."""

    def on_restore(self, env, from_task: str) -> None:  # noqa: B027 (an optional hook, not abstract)
        """Called after an episode starts from a given state saved by sub-task ``from_task`` (forward
        initialization hands over another sub-task's terminal state): tasks that keep per-episode start values
        (start height, start orientation, a goal) set them from that state here."""

    @abc.abstractmethod
    def reward_terms(self, env, action: np.ndarray) -> dict[str, float]:
        """The named reward terms of the current step."""

    @abc.abstractmethod
    def is_success(self, env) -> bool:
        """The sub-task's success test on the current state."""

    def is_failure(self, env) -> bool:
        """Task failure (episode terminated): by default the target object left the table."""
        return bool(env.object_position()[2] < self.config.drop_height)
