"""The task config a run uses, and what a run records about it.

A run (``seqdex train``, a pipeline stage, a shipped chain) trains one sub-task on a :class:`TaskConfig`: the
task's default (``preset="paper"``) or its small-budget variant (``preset="budget"``), optionally with
shortened episodes for smoke tests. This module builds that config (:func:`task_config`), writes and compares it
as plain data (:func:`config_dict`, :func:`same_task_config`), reads back what a run recorded beside its
checkpoint (:func:`run_preset`, :func:`run_residual`) and names the observation layout recorded in buffers, F
files and checkpoints (:func:`observation_spec`). The command line and the chaining code both call it.
"""

import dataclasses
import json
from pathlib import Path

from seqdex_drake.modeling.catalog import object_keys
from seqdex_drake.observation_layout import BASE_SIZE, GOAL_SIZE
from seqdex_drake.observation_spec import ObservationSpec
from seqdex_drake.tasks.base import TaskConfig
from seqdex_drake.tasks.registry import REGISTRY, budget_config, default_config

#: The task variants a run trains on: ``paper`` (each task's default MDP) and ``budget`` (its small-budget
#: variant: the release's scripted phases, shaping terms, a residual base).
PRESETS = ("paper", "budget")

#: Episode length of every sub-task in a test run (``--test``: a few seconds of simulation per run).
TEST_EPISODE_LENGTH = 6


def task_config(task: str, test: bool, preset: str = "paper", residual: bool = True) -> TaskConfig:
    """The :class:`~seqdex_drake.tasks.base.TaskConfig` of a run: the task's default (``preset="budget"``: its
    small-budget variant where it has one), with episodes cut to :data:`TEST_EPISODE_LENGTH` steps when
    ``test``. ``residual=False`` drops the variant's residual base (``TaskConfig.residual``) and gives the
    policy the whole action space back: a policy that sends whole actions, as demonstrations hold them
    (``seqdex train --demos``, ``scripts/collect_demos.py``)."""
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
    config = budget_config(task) if preset == "budget" else default_config(task)
    if not residual and config.residual:
        config = dataclasses.replace(config, residual="", hand_actions=True)
    if test:
        config = dataclasses.replace(config, episode_length=min(config.episode_length, TEST_EPISODE_LENGTH))
    return config


def config_dict(config) -> dict:
    """A dataclass (nested ones included) as JSON-ready plain data (tuples become lists, numpy via ``tolist``)."""
    return json.loads(json.dumps(dataclasses.asdict(config), default=_plain))


def same_task_config(current: dict, recorded: dict) -> bool:
    """Whether a recorded task config (``config_dict`` of a ``TaskConfig``, in a run record or a manifest) is
    ``current``: equal field by field, where a field the record lacks (one added to ``TaskConfig`` since it was
    written) counts as equal only if ``current`` leaves it at its default."""
    if set(recorded) - set(current):
        return False
    defaults = config_dict(TaskConfig())
    return all(current[key] == (recorded[key] if key in recorded else defaults.get(key)) for key in current)


def _plain(value):
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"cannot write {type(value).__name__} to JSON")


def run_preset(checkpoint: Path) -> str:
    """The preset recorded in the run record beside ``checkpoint`` (``config.json`` of ``seqdex train``):
    ``paper`` for runs recorded before presets and for a checkpoint without a readable record."""
    try:
        record = json.loads((Path(checkpoint).parent / "config.json").read_text())
        preset = record.get("preset", "paper")
    except (OSError, ValueError, AttributeError):
        return "paper"
    return preset if preset in PRESETS else "paper"


def run_residual(checkpoint: Path) -> bool:
    """Whether the run beside ``checkpoint`` trained on its task config's residual base: every run except those
    trained with demonstrations (``seqdex train --demos`` trains whole actions; see :func:`task_config`)."""
    try:
        return json.loads((Path(checkpoint).parent / "config.json").read_text()).get("demos") is None
    except (OSError, ValueError, AttributeError):
        return True


def with_objects(config: TaskConfig, task: str, objects: list[str] | None) -> TaskConfig:
    """``config`` drawing its reset's object from ``objects`` (block types ``"1"`` .. ``"8"`` or tool names; as-is
    for None). Raises ValueError for unknown names or a task without objects to choose."""
    if objects is None:
        return config
    family = config.scenario.split("/")[0]
    if family not in ("building_blocks", "tool_positioning"):
        raise ValueError(f"the {task} task has one object, nothing to choose")
    keys = object_keys(family, objects)
    return dataclasses.replace(config, object_types=[int(key) for key in keys])


#: The observation layout of the paper's tables (``seqdex_drake.observation_layout``), for observation specs.
_BASE_LAYOUT = ("joint_q(23) joint_dq(23) fingertips(4x13) palm(13) object(13) previous_action(19) "
                "motor_torque(16)")


def observation_spec(name: str, dim: int) -> ObservationSpec:
    """The :class:`~seqdex_drake.observation_spec.ObservationSpec` of sub-task ``name``'s observations of size
    ``dim`` (goal and pixel parts as the paper's table has), recorded in buffers, F files and checkpoints."""
    task_class = REGISTRY[name][1]
    extras = (" goal(14)" if task_class.goal else "") + (" target_pixels(1)" if task_class.pixels else "")
    paper_size = BASE_SIZE + (GOAL_SIZE if task_class.goal else 0) + (1 if task_class.pixels else 0)
    if dim == paper_size + 1:  # TaskConfig.observe_time: the episode's progress appended.
        extras += " progress(1)"
    return ObservationSpec(dim, f"{name}: {_BASE_LAYOUT}{extras}")
