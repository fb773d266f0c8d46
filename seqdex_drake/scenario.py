"""Scenarios: typed YAML describing one station (models, plant, simulator, robot gains, cameras).

A scenario file (``diagrams/<family>.scenarios.yaml``) holds named scenarios, one per sub-task, derived from
a shared base with YAML anchors. ``LoadScenario`` reads one of them into the :class:`Scenario` dataclass
with ``pydrake.common.yaml.yaml_load_typed`` (unknown keys are errors) and applies an optional YAML override
string, as in RussTedrake/manipulation and Drake's hardware_sim example.
"""


import dataclasses
import math
from pathlib import Path

import numpy as np
import yaml
from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed
from pydrake.multibody.parsing import ModelDirective
from pydrake.multibody.plant import MultibodyPlantConfig
from pydrake.systems.analysis import SimulatorConfig
from pydrake.systems.sensors import CameraConfig
from pydrake.visualization import VisualizationConfig

REPO_ROOT = Path(__file__).resolve().parent.parent
MODELS_DIR = REPO_ROOT / "models"
SCENARIOS_DIR = REPO_ROOT / "diagrams"
MODELS_PACKAGE = "seqdex_models"


class ScenarioError(ValueError):
    """A scenario file, name or override that cannot be used; the message says what to fix."""


@dataclasses.dataclass
class RobotConfig:
    """Gains and control options of the Franka + Allegro, applied to the plant's built-in PD actuators."""

    arm_kp: float = 400.0
    """Franka joint PD stiffness (N m / rad); the release's value."""
    arm_kd: float = 80.0
    """Franka joint PD damping (N m s / rad)."""
    hand_kp: float = 3.0
    """Allegro joint PD stiffness (N m / rad). The release used kp 20 / kd 1 (effort cap 0.7 N m); both hold a
    lifted block (tests/test_grasp_hold.py runs both), and the scripted hand-off resets were tuned at 3."""
    hand_kd: float = 0.1
    """Allegro joint PD damping (N m s / rad)."""
    hand_rotor_inertia: float = 1e-4
    """Reflected motor inertia added to every Allegro joint (kg m^2); keeps 2 ms steps well conditioned."""
    arm_gravity_compensation: bool = True
    """Feed the Franka's gravity torques (controller plant, hand welded) forward into its actuators."""
    arm_home: list[float] = dataclasses.field(
        default_factory=lambda: [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
    """Default Franka joint positions (rad) at which the station starts and holds."""


@dataclasses.dataclass
class FreezeConfig:
    """Freezing of far-away loose blocks (Search scene), see ``seqdex_drake.scene.freezing``."""

    enabled: bool = False
    """Freeze loose objects far from the hand: they stay put, cost no contact solve, and wake when touched."""
    active_radius: float = 0.07
    """Objects whose centre is within this distance (m) of the focus point (the target) stay dynamic at reset."""
    wake_radius: float = 0.09
    """A frozen object whose centre is within this distance (m) of a fingertip or the palm centre wakes (half
    a 1x4 block plus a fingertip and a margin); the robot touching it wakes it too."""
    wake_speed: float = 0.1
    """A dynamic object moving faster than this (m/s) wakes the frozen objects it touches (above the
    point-contact resting jitter of a few cm/s)."""
    sleep_speed: float = 0.01
    """A dynamic object slower than this (m/s) ..."""
    sleep_ticks: int = 30
    """... for this many consecutive control steps, and farther than ``wake_radius`` from the hand, is frozen
    again where it rests (0 disables re-freezing)."""
    mass_scale: float = 100.0
    """Frozen objects' mass multiplier, so a dynamic object resting on one does not push it away."""
    never_wake: list[str] = dataclasses.field(default_factory=list)
    """Name patterns (fnmatch) of objects that, frozen, never wake: supports placed as fixtures (Insert's plates on
    the baseplate, whose undersides overlap the baseplate's studs and would be pushed up if they moved)."""


@dataclasses.dataclass
class Scenario:
    """Everything needed to build one station Diagram."""

    random_seed: int = 0
    """Seeds every random choice of the station (pile selection, object placement)."""
    task_family: str = ""
    """``building_blocks`` or ``tool_positioning``."""
    subtask: str = ""
    """The sub-task this scenario is for (search, orient, grasp, insert, tool_grasp, tool_reorient)."""
    control_period: float = 1.0 / 60.0
    """Policy / controller update period (s); the paper runs every sub-task at 60 Hz."""
    plant_config: MultibodyPlantConfig = dataclasses.field(
        default_factory=lambda: MultibodyPlantConfig(
            time_step=0.002, discrete_contact_approximation="lagged", contact_model="point"))
    """MultibodyPlant settings (time step, contact model, discrete approximation)."""
    simulator_config: SimulatorConfig = dataclasses.field(
        default_factory=lambda: SimulatorConfig(publish_every_time_step=False))
    """Simulator settings; the plant is discrete so the integrator only matters for continuous extras."""
    directives: list[ModelDirective] = dataclasses.field(default_factory=list)
    """Drake model directives: robot, fixtures and objects."""
    objects: list[str] = dataclasses.field(default_factory=list)
    """Model instances of loose objects; each gets a ``<instance>.state`` output port (pose and twist)."""
    object_layout: str = "parked"
    """Initial object placement: ``pile`` (a cached settled pile in the box) or ``parked`` (all objects
    parked off the table, for tasks that place their own target)."""
    pile_file: str = "package://seqdex_models/piles/building_blocks_piles.npz"
    """Cached settled piles (``object_layout: pile``), produced by ``scripts/generate_piles.py``."""
    robot: RobotConfig = dataclasses.field(default_factory=RobotConfig)
    """Gains and control options."""
    freeze: FreezeConfig = dataclasses.field(default_factory=FreezeConfig)
    """Freezing of far-away objects (large piles)."""
    cameras: dict[str, CameraConfig] = dataclasses.field(default_factory=dict)
    """Cameras added with ``ApplyCameraConfig``; ports ``<name>.rgb_image``, ``<name>.label_image``, ..."""
    low_poly_perception: bool = True
    """Cameras render low-poly stand-ins of spheres, capsules, cylinders and of meshes that have a
    ``perception.obj`` beside them (the blocks), ~4x cheaper on a CPU renderer; Meshcat and contact keep the
    full geometry (``scene/perception_geometry.py``). False renders the full visual geometry."""
    visualization: VisualizationConfig = dataclasses.field(default_factory=VisualizationConfig)
    """Meshcat visualization settings, used only when a Meshcat is passed to MakeStation."""


def scenario_files() -> list[Path]:
    """The scenario files shipped in ``diagrams/``."""
    return sorted(SCENARIOS_DIR.glob("*.scenarios.yaml"))


def ScenarioNames(filename: str | Path | None = None) -> list[str]:
    """Names of the scenarios in ``filename`` (``family/name``), or in every shipped file when None.

    Top-level keys starting with an underscore hold YAML anchors (shared bases) and are not scenarios.
    """
    files = [Path(filename)] if filename is not None else scenario_files()
    names = []
    for path in files:
        data = _read_yaml_mapping(path)
        family = path.name.removesuffix(".scenarios.yaml")
        names += [f"{family}/{key}" for key in data if not str(key).startswith("_")]
    return names


class _TaggedSafeLoader(yaml.SafeLoader):
    """A SafeLoader that reads Drake's YAML tags (``!Rpy``, ``!FovDegrees``, ...) as plain nodes."""


def _construct_tagged(loader: yaml.SafeLoader, suffix: str, node: yaml.Node):
    if isinstance(node, yaml.MappingNode):
        return loader.construct_mapping(node, deep=True)
    if isinstance(node, yaml.SequenceNode):
        return loader.construct_sequence(node, deep=True)
    return loader.construct_scalar(node)


_TaggedSafeLoader.add_multi_constructor("!", _construct_tagged)


def _parse_yaml(text: str):
    return yaml.load(text, Loader=_TaggedSafeLoader)  # noqa: S506 (a SafeLoader subclass)


def _read_yaml_mapping(path: Path) -> dict:
    if not path.is_file():
        raise ScenarioError(f"scenario file not found: {path}")
    try:
        data = _parse_yaml(path.read_text())
    except yaml.YAMLError as error:
        raise ScenarioError(f"malformed YAML in scenario file {path}: {error}") from error
    if not isinstance(data, dict):
        raise ScenarioError(f"scenario file {path} must map scenario names to scenarios")
    return data


def _resolve(scenario_name: str, filename: str | Path | None) -> tuple[Path, str]:
    if filename is not None:
        path = Path(filename)
        name = scenario_name.split("/")[-1]
        valid = [n.split("/")[-1] for n in ScenarioNames(path)]
        if name not in valid:
            raise ScenarioError(
                f"unknown scenario '{scenario_name}' in {path}; valid scenarios: {', '.join(valid)}")
        return path, name
    valid = ScenarioNames()
    if "/" in scenario_name:
        matches = [scenario_name] if scenario_name in valid else []
    else:
        matches = [n for n in valid if n.split("/")[1] == scenario_name]
    if len(matches) != 1:
        why = "ambiguous" if matches else "unknown"
        raise ScenarioError(f"{why} scenario '{scenario_name}'; valid scenarios: {', '.join(valid)}")
    family, name = matches[0].split("/")
    return SCENARIOS_DIR / f"{family}.scenarios.yaml", name


def LoadScenario(scenario_name: str, filename: str | Path | None = None,
                 scenario_text: str = "{}") -> Scenario:
    """Loads a named scenario, then applies ``scenario_text`` (a YAML mapping) on top of it.

    Args:
        scenario_name: ``family/name`` (e.g. ``building_blocks/grasp``), or a bare name if unambiguous.
        filename: a scenario file; defaults to the files shipped in ``diagrams/``.
        scenario_text: YAML overrides, e.g. ``"{random_seed: 3, plant_config: {time_step: 0.001}}"``.

    Raises:
        ScenarioError: unknown name (the message lists the valid ones), malformed YAML, unknown keys.
    """
    path, name = _resolve(scenario_name, filename)
    _read_yaml_mapping(path)  # Clear error for malformed files before the typed loader runs.
    try:
        scenario = yaml_load_typed(schema=Scenario, filename=str(path), child_name=name,
                                   defaults=Scenario())
    except Exception as error:  # noqa: BLE001 - Drake's typed loader raises several types for bad values.
        raise ScenarioError(f"invalid scenario '{name}' in {path}: {_reason(error)}") from error
    try:
        _parse_yaml(scenario_text)
    except yaml.YAMLError as error:
        raise ScenarioError(f"malformed YAML in scenario override: {error}") from error
    try:
        scenario = yaml_load_typed(schema=Scenario, data=scenario_text, defaults=scenario)
    except Exception as error:  # noqa: BLE001 - e.g. ValueError for random_seed: "abc", AssertionError for a
        # number where a mapping belongs; every one is a mistake in the text.
        raise ScenarioError(f"invalid scenario override {scenario_text!r}: {_reason(error)}") from error
    _validate(scenario, f"{path}:{name}" if scenario_text.strip() in ("", "{}") else
              f"{path}:{name} with override {scenario_text!r}")
    return scenario


def _reason(error: Exception) -> str:
    """The first line of ``error``'s message, with its type when the message alone says little."""
    text = str(error).strip().splitlines()[0] if str(error).strip() else ""
    if isinstance(error, AssertionError):  # pydrake's loader asserts the YAML node kind.
        return f"a value of the wrong kind (a number or string where a mapping or list belongs?): {text}"
    return text if isinstance(error, RuntimeError) else f"{type(error).__name__}: {text}"


def _non_finite(value, path: str):
    """(path, value) of the first NaN / infinite number in ``value`` (dataclasses, Drake configs, containers and
    arrays are searched field by field), or None."""
    if isinstance(value, bool | str | bytes) or value is None:
        return None
    if isinstance(value, int | float | np.integer | np.floating):
        return None if math.isfinite(value) else (path, value)
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "fc" and not np.all(np.isfinite(value)):
            return path, value.tolist()
        return None
    if dataclasses.is_dataclass(value):
        children = [(field.name, getattr(value, field.name)) for field in dataclasses.fields(value)]
    elif hasattr(type(value), "__fields__"):  # Drake's serializable config structs (MultibodyPlantConfig, ...).
        children = [(field.name, getattr(value, field.name)) for field in type(value).__fields__]
    elif isinstance(value, dict):
        children = list(value.items())
    elif isinstance(value, list | tuple):
        children = [(f"[{index}]", item) for index, item in enumerate(value)]
    else:
        return None
    for name, child in children:
        found = _non_finite(child, f"{path}{name}" if name.startswith("[") or not path else f"{path}.{name}")
        if found is not None:
            return found
    return None


def _validate(scenario: Scenario, where: str) -> None:
    """Raises :class:`ScenarioError` for values no station can be built or stepped with (NaN / inf anywhere,
    non-positive periods, negative gains, seeds or counts); the message names the field."""
    found = _non_finite(scenario, "")
    if found is not None:
        raise ScenarioError(f"{where}: {found[0]} must be finite, got {found[1]}")
    if scenario.random_seed < 0:
        raise ScenarioError(f"{where}: random_seed must be >= 0, got {scenario.random_seed}")
    if scenario.control_period <= 0:
        raise ScenarioError(f"{where}: control_period must be a positive number of seconds")
    if scenario.plant_config.time_step <= 0:
        raise ScenarioError(f"{where}: plant_config.time_step must be > 0 (the station uses a discrete plant)")
    ratio = scenario.control_period / scenario.plant_config.time_step
    if abs(ratio - round(ratio)) > 1e-6 and ratio < 1:
        raise ScenarioError(f"{where}: plant_config.time_step must not exceed control_period")
    if scenario.object_layout not in ("pile", "parked"):
        raise ScenarioError(f"{where}: object_layout must be 'pile' or 'parked', not '{scenario.object_layout}'")
    robot, freeze = scenario.robot, scenario.freeze
    for name in ("arm_kp", "arm_kd", "hand_kp", "hand_kd", "hand_rotor_inertia"):
        if getattr(robot, name) < 0:
            raise ScenarioError(f"{where}: robot.{name} must be >= 0, got {getattr(robot, name)}")
    if len(robot.arm_home) != 7:
        raise ScenarioError(f"{where}: robot.arm_home must hold the 7 Franka joint positions, got "
                            f"{len(robot.arm_home)}")
    for name in ("active_radius", "wake_radius", "wake_speed", "sleep_speed", "sleep_ticks"):
        if getattr(freeze, name) < 0:
            raise ScenarioError(f"{where}: freeze.{name} must be >= 0, got {getattr(freeze, name)}")
    if freeze.mass_scale <= 0:
        raise ScenarioError(f"{where}: freeze.mass_scale must be > 0, got {freeze.mass_scale}")


def DumpScenario(scenario: Scenario) -> str:
    """The resolved scenario as YAML text (written into every run directory)."""
    return yaml_dump_typed(scenario)
