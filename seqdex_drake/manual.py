"""Assembly manuals: typed YAML listing the blocks to build, in order, with their goal poses on the baseplate.

A manual (``diagrams/manuals/*.yaml``) loads into :class:`AssemblyManual` with Drake's ``yaml_load_typed``
(unknown keys are errors) and is then validated; every problem is a :class:`ManualError` whose message names
the file, the step and what to fix. Each step is one Search -> Orient -> Grasp -> Insert run of the Building
Blocks chain. A step's goal is given either on the stud grid or as a position:

``cell: [i, j]`` and ``level: L``
    The block's footprint starts at stud cell (i, j) of the 12 x 12 baseplate (i along world x, j along
    world y, 0-11, as in ``tasks/insert.goal_pose``) and sits L block layers (0.0375 m each) above the
    baseplate top (0: on the baseplate). ``yaw_deg`` must then be a multiple of 90. A block above level 0
    needs an earlier block under one of its cells, and two blocks may not share a cell.
``position: [x, y, z]``
    The block frame's origin (bottom centre) in the world; the rotated footprint must lie on the baseplate
    and z at or above its top. Any ``yaw_deg``.

    name: small wall
    steps:
    - {block_type: 5, cell: [4, 9], level: 0, yaw_deg: 0}
    - {block_type: 1, cell: [5, 9], level: 1}
"""

import dataclasses
import math
from pathlib import Path

import numpy as np
import yaml
from pydrake.common.yaml import yaml_load_typed
from pydrake.math import RigidTransform, RollPitchYaw

from seqdex_drake.modeling.blocks import BLOCK_SPECS, BODY_HEIGHT, STUD_PITCH
from seqdex_drake.modeling.fixtures import BASEPLATE_STUDS, BASEPLATE_THICKNESS
from seqdex_drake.observation_layout import pose_vector
from seqdex_drake.scenario import REPO_ROOT

MANUALS_DIR = REPO_ROOT / "diagrams" / "manuals"
#: The baseplate's bottom centre in the world (``models/fixtures_boards.dmd.yaml`` and the chain scenario).
BOARD_ORIGIN = np.array([0.25, -0.35, 0.6])
BOARD_TOP = BOARD_ORIGIN[2] + BASEPLATE_THICKNESS
BOARD_HALF = BASEPLATE_STUDS * STUD_PITCH / 2
#: Highest level accepted (a stack of 8 blocks is already 0.3 m tall).
MAX_LEVEL = 7
TOLERANCE = 1e-3


class ManualError(ValueError):
    """An assembly manual that cannot be used; the message names the file, the step and the problem."""


@dataclasses.dataclass
class ManualStep:
    """One block of an assembly manual."""

    block_type: int = 0
    """Block type 1-8 (FACTS.md: 1-5 trained, 6-8 unseen)."""
    cell: list[int] | None = None
    """Stud cell [i, j] (0-11) of the baseplate where the footprint's -x/-y corner cell goes."""
    level: int = 0
    """Block layers above the baseplate top, with ``cell`` (0: on the baseplate)."""
    position: list[float] | None = None
    """World position [x, y, z] of the block's origin (bottom centre), instead of ``cell``/``level``."""
    yaw_deg: float = 0.0
    """Yaw about world z (deg); a multiple of 90 with ``cell``."""


@dataclasses.dataclass
class AssemblyManual:
    """What to build: blocks in the order they are placed."""

    name: str = ""
    """A short title shown in meshcat and the logs."""
    description: str = ""
    """Free text."""
    steps: list[ManualStep] = dataclasses.field(default_factory=list)
    """The blocks, in placing order."""


def _footprint_cells(step: ManualStep) -> tuple[int, int]:
    nx, ny = BLOCK_SPECS[step.block_type].cells
    return (ny, nx) if round(step.yaw_deg / 90) % 2 else (nx, ny)


def goal_pose(step: ManualStep) -> RigidTransform:
    """World pose of the block frame (bottom centre) at the step's goal."""
    yaw = math.radians(step.yaw_deg)
    if step.position is not None:
        return RigidTransform(RollPitchYaw(0.0, 0.0, yaw), np.asarray(step.position, dtype=float))
    span = np.array(_footprint_cells(step))
    offset = (np.asarray(step.cell) + span / 2 - BASEPLATE_STUDS / 2) * STUD_PITCH
    return RigidTransform(RollPitchYaw(0.0, 0.0, yaw),
                          [*(BOARD_ORIGIN[:2] + offset), BOARD_TOP + step.level * BODY_HEIGHT])


def goal_vector(step: ManualStep) -> np.ndarray:
    """The goal as the Insert observation has it: [x, y, z, qw, qx, qy, qz]."""
    return pose_vector(goal_pose(step))


def _where(source: str, index: int, step: ManualStep) -> str:
    return f"{source}: step {index + 1} (block {step.block_type})"


def _check_step(source: str, index: int, step: ManualStep) -> None:
    where = f"{source}: step {index + 1}"
    if step.block_type not in BLOCK_SPECS:
        raise ManualError(f"{where}: unknown block type {step.block_type}; valid types are "
                          f"{sorted(BLOCK_SPECS)} (1-5 trained, 6-8 unseen)")
    where = _where(source, index, step)
    if (step.cell is None) == (step.position is None):
        raise ManualError(f"{where}: give the goal either as 'cell' (with 'level') or as 'position', exactly one")
    if not math.isfinite(step.yaw_deg):
        raise ManualError(f"{where}: yaw_deg must be a finite number of degrees")
    if step.cell is not None:
        if len(step.cell) != 2:
            raise ManualError(f"{where}: cell must be [i, j], got {step.cell}")
        if abs(step.yaw_deg / 90 - round(step.yaw_deg / 90)) > 1e-9:
            raise ManualError(f"{where}: with 'cell' the yaw must be a multiple of 90 deg (stud-aligned), "
                              f"got {step.yaw_deg}; use 'position' for other yaws")
        if not 0 <= step.level <= MAX_LEVEL:
            raise ManualError(f"{where}: level {step.level} is off the board's stack (valid levels: 0-{MAX_LEVEL})")
        span = _footprint_cells(step)
        last = BASEPLATE_STUDS - 1
        if min(step.cell) < 0 or step.cell[0] + span[0] - 1 > last or step.cell[1] + span[1] - 1 > last:
            raise ManualError(f"{where}: goal off the board: a {span[0]}x{span[1]}-cell footprint at cell "
                              f"{list(step.cell)} reaches past the {BASEPLATE_STUDS}x{BASEPLATE_STUDS} baseplate "
                              f"(cells 0-{last}; the first cell may be at most "
                              f"[{BASEPLATE_STUDS - span[0]}, {BASEPLATE_STUDS - span[1]}])")
        return
    position = np.asarray(step.position, dtype=float)
    if position.shape != (3,) or not np.all(np.isfinite(position)):
        raise ManualError(f"{where}: position must be [x, y, z] in metres, got {step.position}")
    X_WB = goal_pose(step)
    length, width = BLOCK_SPECS[step.block_type].footprint
    corners = np.array([X_WB @ [sx * length / 2, sy * width / 2, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
    reach = np.max(np.abs(corners[:, :2] - BOARD_ORIGIN[:2]), axis=0)
    if np.any(reach > BOARD_HALF + TOLERANCE):
        raise ManualError(f"{where}: goal off the board: the footprint at {np.round(position, 4).tolist()} "
                          f"(yaw {step.yaw_deg} deg) reaches {np.round(reach, 3).tolist()} m from the baseplate "
                          f"centre {BOARD_ORIGIN[:2].tolist()}, beyond its half-size {BOARD_HALF} m")
    top = BOARD_TOP + MAX_LEVEL * BODY_HEIGHT
    if not BOARD_TOP - TOLERANCE <= position[2] <= top + TOLERANCE:
        raise ManualError(f"{where}: goal off the board: z = {position[2]} m is not between the baseplate top "
                          f"{BOARD_TOP} m and level {MAX_LEVEL} ({top:.4f} m)")


def _check_stacking(source: str, manual: AssemblyManual) -> None:
    """Cell-placed blocks: no two share a cell, and each one above level 0 rests on an earlier block."""
    occupied: dict[tuple[int, int, int], int] = {}
    for index, step in enumerate(manual.steps):
        if step.cell is None:
            continue
        span = _footprint_cells(step)
        cells = [(step.cell[0] + di, step.cell[1] + dj) for di in range(span[0]) for dj in range(span[1])]
        for i, j in cells:
            if (i, j, step.level) in occupied:
                raise ManualError(f"{_where(source, index, step)}: cell [{i}, {j}] at level {step.level} is already "
                                  f"taken by step {occupied[(i, j, step.level)] + 1}")
        if step.level > 0 and not any((i, j, step.level - 1) in occupied for i, j in cells):
            raise ManualError(f"{_where(source, index, step)}: nothing under it at level {step.level - 1}; place a "
                              f"supporting block in an earlier step or lower the level")
        occupied.update({(i, j, step.level): index for i, j in cells})


def pinch_conflicts(manual: AssemblyManual) -> list[str]:
    """Steps whose block the chain's hand cannot set down: an earlier cell-placed block in a cell next to its
    footprint along world x, at its level or above. Grasp's pinch holds every block across world x (the wrist
    does not turn), its index and middle tips on the block's +x face and the thumb on its -x face, 6-12 mm above
    the block's bottom; the block is as wide as a stud cell (both 3 cm), so a neighbour along x leaves the
    fingers no room and Insert lands the block on it. Neighbours along y are fine. One line per conflict
    (empty when the hand can build the manual); shown by the main command, not an error (the structure is valid)."""
    occupied: dict[tuple[int, int, int], int] = {}
    problems = []
    for index, step in enumerate(manual.steps):
        if step.cell is None:
            continue
        span = _footprint_cells(step)
        rows = range(step.cell[1], step.cell[1] + span[1])
        sides = (step.cell[0] - 1, step.cell[0] + span[0])
        blockers = sorted({occupied[(i, j, level)] + 1 for i in sides for j in rows for level in
                           range(step.level, MAX_LEVEL + 1) if (i, j, level) in occupied})
        if blockers:
            problems.append(f"step {index + 1} (block {step.block_type}): step(s) {blockers} beside it along "
                            f"world x leave the pinch's fingers no room (leave a free cell along x, or put "
                            f"neighbours along y)")
        occupied.update({(step.cell[0] + di, step.cell[1] + dj, step.level): index for di in range(span[0])
                         for dj in range(span[1])})
    return problems


def _check_keys(source: str, data) -> None:
    """Unknown keys, named with their step (yaml_load_typed's message does not say which step)."""
    if not isinstance(data, dict):
        raise ManualError(f"{source}: a manual is a mapping with 'name', 'description' and 'steps'")
    valid = [f.name for f in dataclasses.fields(AssemblyManual)]
    unknown = [k for k in data if k not in valid]
    if unknown:
        raise ManualError(f"{source}: unknown key(s) {unknown}; valid keys: {valid}")
    steps = data.get("steps") or []
    if not isinstance(steps, list):
        raise ManualError(f"{source}: 'steps' must be a list of steps")
    valid = [f.name for f in dataclasses.fields(ManualStep)]
    for index, step in enumerate(steps):
        if not isinstance(step, dict):
            raise ManualError(f"{source}: step {index + 1} must be a mapping with the keys {valid}")
        unknown = [k for k in step if k not in valid]
        if unknown:
            raise ManualError(f"{source}: step {index + 1}: unknown key(s) {unknown}; valid keys: {valid}")
        block_type = step.get("block_type")
        if block_type is not None and (not isinstance(block_type, int) or isinstance(block_type, bool)):
            raise ManualError(f"{source}: step {index + 1}: unknown block type {block_type!r}; valid types are "
                              f"{sorted(BLOCK_SPECS)} (1-5 trained, 6-8 unseen)")


def ManualPath(name: str | Path) -> Path:
    """A manual file: an existing path, or the name of one in ``diagrams/manuals/`` (with or without .yaml)."""
    path = Path(name)
    if path.is_file():
        return path
    for candidate in (MANUALS_DIR / f"{name}.yaml", MANUALS_DIR / str(name)):
        if candidate.is_file():
            return candidate
    shipped = ", ".join(ManualNames()) or "none"
    raise ManualError(f"assembly manual '{name}' not found (not a file; shipped manuals: {shipped})")


def ManualNames() -> list[str]:
    """Names of the manuals shipped in ``diagrams/manuals/``."""
    return sorted(p.stem for p in MANUALS_DIR.glob("*.yaml"))


def LoadManual(name: str | Path | None = None, text: str | None = None) -> AssemblyManual:
    """Loads and validates a manual from a file (path or shipped name) or from YAML ``text``.

    Raises:
        ManualError: missing file, malformed YAML, unknown keys, wrong value types, unknown block type, a goal
            off the board, overlapping or unsupported blocks, no steps. The message names the step.
    """
    if (name is None) == (text is None):
        raise ValueError("pass exactly one of a manual name/path or YAML text")
    if text is None:
        path = ManualPath(name)
        source, text = str(path), path.read_text()
    else:
        source = "manual text"
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise ManualError(f"{source}: malformed YAML: {error}") from error
    _check_keys(source, data)
    try:
        manual = yaml_load_typed(schema=AssemblyManual, data=text, defaults=AssemblyManual())
    except (RuntimeError, ValueError, TypeError) as error:  # Drake's typed YAML: unknown keys, wrong types.
        raise ManualError(f"{source}: {error}") from error
    if not manual.steps:
        raise ManualError(f"{source}: the manual has no steps")
    for index, step in enumerate(manual.steps):
        _check_step(source, index, step)
    _check_stacking(source, manual)
    return manual
