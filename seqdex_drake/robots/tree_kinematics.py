"""Compiled forward kinematics of a few frames of a MultibodyPlant: poses, velocities and a DLS IK step.

Every env step needs the poses and spatial velocities of six frames (the four fingertips, the palm and the
object) for the observation, and the palm pose and its Jacobian for the wrist IK. Drake computes them in
microseconds, but the step runs right after ~5-10 ms of physics has evicted the interpreter's and Drake's code
from the CPU caches; there each Drake call from Python and each line of float arithmetic costs far more, and
these two parts took ~400 us of a ~5 ms tool-grasp step (docs/performance.md, "How the env time is spent").

:class:`TreeKinematics` reads, once, the part of the plant's tree that holds the given frames (each body's
inboard joint: revolute, prismatic, weld or quaternion floating, its fixed frame offsets and axis) into a
flat table, and evaluates it in a small C extension (``_kinematics.c``, built at install): one call per step,
microseconds, the same products as Drake's to ~1e-15 (``tests/test_tree_kinematics.py`` compares them with
``EvalBodyPoseInWorld``, ``EvalBodySpatialVelocityInWorld`` and ``CalcJacobianSpatialVelocity``).

The table holds the plant's *default* frame offsets: a plant whose frame offsets are parameters changed in a
context is not followed (domain randomization scales masses, inertias, friction, joint limits, stiffness and
damping, and object geometry, not frame offsets).

Without the C extension. The extension is optional at install: where no C compiler or no Python headers were
there, the install goes on without it, and :class:`TreeKinematics` answers the same calls from Drake's own
kinematics (:class:`~seqdex_drake.robots.drake_kinematics.DrakeKinematics`: the same results to ~1e-13, several
Drake calls per step instead of one compiled call, so env steps are slower). The first such
:class:`TreeKinematics` of a process warns once (:class:`SlowKinematicsWarning`, naming the fix: install gcc
and python3-dev, then rerun ``bash scripts/venv.sh``); child processes started after it stay quiet.
Set ``SEQDEX_NO_C_EXTENSION=1`` to use Drake's kinematics although the extension is built (to compare the two;
no warning then); ``TreeKinematics(..., compiled=False)`` does the same for one instance.
"""

import os
import warnings
from collections.abc import Sequence

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import Frame, PrismaticJoint, QuaternionFloatingJoint, RevoluteJoint, WeldJoint

from seqdex_drake.robots import drake_kinematics

try:
    from seqdex_drake.robots import _kinematics
except ImportError as error:  # An install without a C compiler or Python's headers: Drake's kinematics instead.
    _kinematics, _IMPORT_ERROR = None, error
else:
    _IMPORT_ERROR = None

FORCE_DRAKE_VARIABLE = "SEQDEX_NO_C_EXTENSION"
"""Set to 1 to use Drake's kinematics although the C extension is built (no warning)."""
_WARNED_VARIABLE = "SEQDEX_KINEMATICS_WARNED"  # Set once warned: child processes (env workers) stay quiet.
_FIXED, _REVOLUTE, _PRISMATIC, _FLOATING = 0.0, 1.0, 2.0, 3.0
_IDENTITY = RigidTransform()


class SlowKinematicsWarning(RuntimeWarning):
    """The C extension is not built: TreeKinematics runs on Drake's kinematics (the same results, slower)."""


def compiled_available() -> bool:
    """Whether the C extension ``seqdex_drake.robots._kinematics`` was built and imported."""
    return _kinematics is not None


def _use_compiled(compiled: bool | None) -> bool:
    """Resolves :class:`TreeKinematics`' ``compiled`` argument; warns once per process tree when the extension
    is wanted (the default) but not built."""
    if compiled is not None:
        if compiled and _kinematics is None:
            raise ImportError(f"TreeKinematics(compiled=True): the C extension is not built ({_IMPORT_ERROR})")
        return compiled
    if os.environ.get(FORCE_DRAKE_VARIABLE, "") not in ("", "0"):
        return False
    if _kinematics is None and not os.environ.get(_WARNED_VARIABLE):
        os.environ[_WARNED_VARIABLE] = "1"
        warnings.warn(
            f"seqdex_drake's compiled kinematics (seqdex_drake/robots/_kinematics.c) is not built ({_IMPORT_ERROR}); "
            "using Drake's kinematics instead: the same results, slower env steps. To build it, install a C "
            "compiler and Python's headers (apt-get install gcc python3-dev) and rerun `bash scripts/venv.sh`.",
            SlowKinematicsWarning, stacklevel=3)
    return _kinematics is not None


def _pose_entries(X: RigidTransform) -> list[float]:
    """R row by row (9), then p (3): the C side's pose layout."""
    return X.rotation().matrix().ravel().tolist() + X.translation().tolist()


class TreeKinematics:
    """Poses and spatial velocities of ``frames`` of ``plant`` (or of points offset in them), computed from the
    plant's state in one compiled call.

    Args:
        plant: a finalized MultibodyPlant (double).
        frames: the frames to evaluate.
        X_FQ: optional per-frame offsets: evaluate the frame Q fixed in each frame F at ``X_FQ[i]`` instead.
        compiled: True: the C extension; False: Drake's kinematics; None (default): the C extension when it is
            built and ``SEQDEX_NO_C_EXTENSION`` is not set, else Drake's (see the module docstring).

    Raises:
        ValueError: a joint on a frame's path to the world is not revolute, prismatic, weld or quaternion
            floating (an RPY floating joint, a ball joint, ...), or the tree is too large (256 links).
    """

    def __init__(self, plant: MultibodyPlant, frames: Sequence[Frame], X_FQ: Sequence[RigidTransform] | None = None,
                 compiled: bool | None = None):
        if not plant.is_finalized():
            raise ValueError("TreeKinematics: finalize the plant first")
        if X_FQ is not None and len(X_FQ) != len(frames):
            raise ValueError(f"TreeKinematics: {len(frames)} frames but {len(X_FQ)} offsets X_FQ")
        if not 1 <= len(frames) <= 64:
            raise ValueError(f"TreeKinematics: between 1 and 64 frames, got {len(frames)}")
        inboard = {}  # Child body index -> the joint connecting it to its parent.
        for index in plant.GetJointIndices():
            joint = plant.get_joint(index)
            inboard[joint.child_body().index()] = joint
        world = plant.world_body().index()
        paths = []  # Per frame, its body's path of (body index, joint) from the world.
        for frame in frames:
            path, body = [], frame.body()
            while body.index() != world:
                if body.index() not in inboard:
                    raise ValueError(f"TreeKinematics: body '{body.name()}' has no inboard joint")
                path.append((body.index(), inboard[body.index()]))
                body = inboard[body.index()].parent_body()
            paths.append(path[::-1])
        links, table = {}, []  # Body index -> link index (parents first), the table's rows.
        for path in paths:
            for body, joint in path:
                if body not in links:
                    parent = joint.parent_body().index()
                    table.append(self._link(-1.0 if parent == world else float(links[parent]), joint))
                    links[body] = len(table) - 1
        if len(table) > 256:
            raise ValueError(f"TreeKinematics: at most 256 links, the frames need {len(table)}")
        header = [float(len(table)), float(plant.num_positions()), float(plant.num_velocities())]
        self.model = np.array(header + [v for row in table for v in row], dtype=np.float64).tobytes()
        entries = []
        for i, frame in enumerate(frames):
            X_BQ = frame.GetFixedPoseInBodyFrame() @ (X_FQ[i] if X_FQ is not None else _IDENTITY)
            entries += [float(links[frame.body().index()])] + _pose_entries(X_BQ)
        self.frames = np.array(entries, dtype=np.float64).tobytes()
        self.size = len(frames)
        self.num_positions, self.num_velocities = plant.num_positions(), plant.num_velocities()
        self.compiled = _use_compiled(compiled)  # The calls run in the C extension, else on Drake's kinematics.
        self._drake = None if self.compiled else drake_kinematics.DrakeKinematics(plant, frames, X_FQ)

    @staticmethod
    def _link(parent: float, joint) -> list[float]:
        """One table row: [parent, type, q start, v start, X_PF (12), axis (3), X_MC (12)]."""
        X_PF = joint.frame_on_parent().GetFixedPoseInBodyFrame()
        X_MC = joint.frame_on_child().GetFixedPoseInBodyFrame().inverse()
        axis, start = [0.0, 0.0, 0.0], (0.0, 0.0)
        if isinstance(joint, WeldJoint):
            kind, X_PF = _FIXED, X_PF @ joint.X_FM()
        elif isinstance(joint, RevoluteJoint | PrismaticJoint):
            kind = _REVOLUTE if isinstance(joint, RevoluteJoint) else _PRISMATIC
            axis = (joint.revolute_axis() if kind == _REVOLUTE else joint.translation_axis()).tolist()
            start = (float(joint.position_start()), float(joint.velocity_start()))
        elif isinstance(joint, QuaternionFloatingJoint):
            kind, start = _FLOATING, (float(joint.position_start()), float(joint.velocity_start()))
        else:
            raise ValueError(f"TreeKinematics: joint '{joint.name()}' is a {joint.type_name()} joint; only "
                             "revolute, prismatic, weld and quaternion floating joints are supported")
        return [parent, kind, *start] + _pose_entries(X_PF) + axis + _pose_entries(X_MC)

    def states(self, x) -> list[float]:
        """Per frame, 13 floats: position (3), quaternion [w, x, y, z] with w >= 0 (4), the frame origin's
        translational velocity (3) and the frame's angular velocity (3), all in the world, from the plant's
        state ``x`` = [q, v] (a list of floats is fastest; an array works)."""
        if self._drake is not None:
            return self._drake.states(x)
        return _kinematics.frame_states(self.model, self.frames, x)

    def poses(self, q) -> list[float]:
        """Per frame, 12 floats: X_WF's rotation row by row (9), then its translation (3), from the plant's
        positions ``q`` (or its whole state [q, v])."""
        if self._drake is not None:
            return self._drake.poses(q)
        return _kinematics.frame_poses(self.model, self.frames, q)

    def pose(self, q, i: int = 0) -> RigidTransform:
        """Frame ``i``'s pose X_WF as a RigidTransform (see :meth:`poses`)."""
        entries = self.poses(q)[12 * i:12 * i + 12]
        return RigidTransform(RotationMatrix(np.reshape(entries[:9], (3, 3))), entries[9:])

    def dls_step(self, q, p_WQ_target, R_WQ_target: list[float], orientation_weight: float, damping: float,
                 max_step: float, q_min: list[float], q_max: list[float]) -> list[float]:
        """One damped least-squares IK step for the (single) frame Q: positions q + dq, where
        dq = J^T (J J^T + damping^2 I)^-1 e for the error e = [w log(R_target R_WQ^T); p_target - p_WQ] and Q's
        spatial Jacobian J (its angular rows times w = ``orientation_weight``), scaled to a norm of at most
        ``max_step`` and clamped to [q_min, q_max]. ``R_WQ_target``: 9 floats, row by row. The plant's
        positions must all be revolute or prismatic joints on Q's path (e.g. the controller plant)."""
        if self.size != 1:
            raise ValueError("TreeKinematics.dls_step: build the kinematics with a single frame")
        if self._drake is not None:
            return self._drake.dls_step(q, p_WQ_target, R_WQ_target, orientation_weight, damping, max_step, q_min,
                                        q_max)
        return _kinematics.dls_step(self.model, self.frames, q, p_WQ_target, R_WQ_target, orientation_weight,
                                    damping, max_step, q_min, q_max)


def rotation_vector(R, compiled: bool | None = None) -> list[float]:
    """angle * axis of a rotation matrix (its log map, for any angle up to a half turn), an array or rows;
    ``compiled`` as :class:`TreeKinematics`'."""
    if not _use_compiled(compiled):
        return drake_kinematics.rotation_vector(R)
    return _kinematics.rotation_vector(np.asarray(R, dtype=float).ravel().tolist())
