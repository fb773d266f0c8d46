"""Settled piles of blocks in the box: made once by simulation, cached in a file, restored by a state write.

The paper drops the blocks above the box and lets them fall (appendix, Initialization). Settling 72
dynamic blocks runs at about 10 control steps per second in Drake, so :func:`SettlePile` drops them in
batches: each batch falls onto the earlier ones, which are frozen (static supports, see
``scene/freezing.py``), then one last all-dynamic phase lets the whole pile relax together.
:func:`SavePiles` / :func:`LoadPiles` keep the results in a versioned ``.npz``.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
from pydrake.common import RandomGenerator
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.analysis import Simulator

from seqdex_drake.atomic import atomic_write
from seqdex_drake.scene.objects import SceneObjects

PILE_FILE_VERSION = 1

#: The box (FACTS.md): inner footprint 0.60 x 0.416 m centred at (0.25, 0.19), floor at z = 0.6.
BOX_CENTER = np.array([0.25, 0.19, 0.6])
BOX_INNER_HALF = np.array([0.30, 0.208])
BOX_WALL_HEIGHT = 0.165
#: Plant step (s) the cached piles are settled at (``scripts/generate_piles.py``): finer than the Search scene's
#: own 1/240 s step, so that the piles rest as quasi-statically as an all-dynamic pile can under point contact.
SETTLE_TIME_STEP = 0.002


@dataclasses.dataclass
class PileSettings:
    """How piles are dropped and settled."""

    grid: tuple[int, int] = (4, 3)
    """Release cells along x and y: one block per cell per batch, so released blocks never overlap."""
    batch_seconds: float = 0.6
    """Simulated time a batch falls and settles before it is frozen."""
    relax_seconds: float = 0.4
    """Final all-dynamic settling time."""
    drop_height: float = 0.10
    """Height (m) above the current pile top at which a batch is released."""
    jitter: float = 0.006
    """Random offset (m) of a release position from its cell centre."""


def InsideBox(q_objects: np.ndarray, tolerance: float = 0.005) -> np.ndarray:
    """Mask of objects whose origin is inside the box (footprint and below the wall top)."""
    p = np.asarray(q_objects)[:, 4:]
    inside_xy = np.all(np.abs(p[:, :2] - BOX_CENTER[:2]) <= BOX_INNER_HALF + tolerance, axis=1)
    inside_z = (p[:, 2] > BOX_CENTER[2] - tolerance) & (p[:, 2] < BOX_CENTER[2] + BOX_WALL_HEIGHT)
    return inside_xy & inside_z


def SettlePile(simulator: Simulator, objects: SceneObjects, seed: int,
               settings: PileSettings | None = None) -> np.ndarray:
    """Drops every object of ``objects`` into the box and returns the settled (n, 7) positions.

    ``simulator`` must simulate the station that ``objects`` manages, with the robot holding a pose clear
    of the box. Deterministic for a given seed.
    """
    settings = settings or PileSettings()
    generator = RandomGenerator(seed)
    root = simulator.get_mutable_context()
    objects.park(root)
    order = list(range(len(objects.names)))
    _shuffle(order, generator)
    nx, ny = settings.grid
    cell = 2 * BOX_INNER_HALF / [nx, ny]
    centers = [BOX_CENTER[:2] - BOX_INNER_HALF + cell * ([i, j] + np.array([0.5, 0.5]))
               for i in range(nx) for j in range(ny)]
    placed: list[int] = []
    for start in range(0, len(order), nx * ny):
        batch = order[start:start + nx * ny]
        top = max([BOX_CENTER[2]] + [objects.positions(root)[i, 6] for i in placed])
        for k, i in enumerate(batch):
            xy = centers[k] + settings.jitter * (2 * _uniform(generator, 2) - 1)
            rpy = RollPitchYaw(*(np.pi * (2 * _uniform(generator, 3) - 1)))
            X_WB = RigidTransform(rpy, [*xy, top + settings.drop_height])
            objects.set_pose(root, objects.names[i], X_WB, frozen=False)
        mask = np.ones(len(objects.names), dtype=bool)
        mask[batch] = False
        objects.set_frozen(root, mask)
        simulator.AdvanceTo(root.get_time() + settings.batch_seconds)
        placed += batch
    objects.set_frozen(root, np.zeros(len(objects.names), dtype=bool))
    simulator.AdvanceTo(root.get_time() + settings.relax_seconds)
    return objects.positions(root)


def _uniform(generator: RandomGenerator, n: int) -> np.ndarray:
    return np.array([generator() for _ in range(n)]) / 2**32


def _shuffle(items: list, generator: RandomGenerator) -> None:
    for i in range(len(items) - 1, 0, -1):
        j = int(generator() % (i + 1))
        items[i], items[j] = items[j], items[i]


def SavePiles(path: str | Path, piles: np.ndarray, object_names: list[str], scenario_name: str) -> None:
    """Writes piles atomically (temporary file, fsync, rename) in the versioned format."""
    def write(stream) -> None:
        np.savez(stream, version=PILE_FILE_VERSION, q=np.asarray(piles, dtype=np.float64),
                 object_names=np.array(object_names), scenario=np.array(scenario_name))

    os.chmod(atomic_write(path, write), 0o644)


def LoadPiles(path: str | Path, object_names: list[str]) -> np.ndarray:
    """Reads cached piles, checking the format version and that they were made for these objects."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"pile cache {path} not found; make it with: python scripts/generate_piles.py")
    with np.load(path, allow_pickle=False) as data:
        version = int(data["version"])
        if version != PILE_FILE_VERSION:
            raise ValueError(f"pile cache {path} has format version {version}, expected {PILE_FILE_VERSION}; "
                             "regenerate it with: python scripts/generate_piles.py")
        names = [str(n) for n in data["object_names"]]
        if names != list(object_names):
            raise ValueError(f"pile cache {path} was made for other objects ({len(names)} objects); "
                             "regenerate it with: python scripts/generate_piles.py")
        return np.array(data["q"])
