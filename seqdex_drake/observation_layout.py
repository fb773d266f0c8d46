"""The observation layout: where each quantity sits in the paper's state vectors, and the small pure-Python
helpers that write and read those entries.

Layout (indices as in the paper's tables, appendix "State Space in Simulation"; poses are 7 = position +
quaternion wxyz, velocities linear then angular, all in the world frame as in the authors' release):

====================  =========  ==========================================================
indices               size       content
====================  =========  ==========================================================
0-23                  23         joint positions, canonical order (Franka 1-7, Allegro 0-15)
23-46                 23         joint velocities
46-98                 4 x 13     fingertip pose, linear velocity, angular velocity
98-111                13         hand base (palm) pose, linear, angular velocity
111-124               13         object pose, linear, angular velocity
124-143               19         previous action (16 hand joints + 3 wrist translation)
143-159               16         motor tactile: torques the 16 Allegro motors exert
159-160 (Search)      1          target-object pixels in the top-down label image
159-173 (Insert)      14         goal pose (7), goal - object position (3), goal * conj(object) quaternion (4)
====================  =========  ==========================================================

Orient, Grasp and tool Grasp use the 159-dim base; Insert and tool Reorient append the goal (173); Search
appends the pixel count (160).

Why this sits at the bottom of the package: the sub-tasks (``tasks/``: rewards, success tests, goal errors), the
env (``envs/subtask_env.py``), the arm IK and the deployed systems all read the same indices, while only the Drake
system that *assembles* the vector (:class:`~seqdex_drake.sensors.observations.ObservationAssembler`) belongs to
``sensors/``. Keeping the layout in the plain-data layer lets every layer read it. This module
imports numpy only (``pose_vector`` takes any RigidTransform-like object); ``sensors/observations.py`` re-exports
every name defined here.
"""

import numpy as np

BASE_SIZE = 159
"""Size of the base observation (Orient, Grasp, tool Grasp, Reach, Lower)."""
ACTION_SIZE = 19
"""Size of an action (16 hand joints + 3 wrist translation), also stored in the observation."""
GOAL_SIZE = 14
"""Entries appended for a goal pose (Insert, tool Reorient)."""

#: Parts of an observation that the env and the tasks read back (indices as in the table above).
FINGERTIPS = slice(46, 98)
"""The 4 fingertip rows of 13 (pose, linear, angular velocity)."""
PALM_POSE = slice(98, 105)
"""The palm (hand base) pose [x, y, z, qw, qx, qy, qz]."""
OBJECT_POSE = slice(111, 118)
"""The object's pose [x, y, z, qw, qx, qy, qz]."""
OBJECT_QUATERNION = slice(114, 118)
"""The object's orientation [qw, qx, qy, qz], qw >= 0."""
PREVIOUS_ACTION = slice(124, 143)
"""The action applied at the previous step (16 hand entries, then 3 wrist)."""
MOTOR_TACTILE = slice(143, 159)
"""The torques the 16 Allegro motors exert."""
GOAL_POSITION_ERROR = slice(166, 169)
"""Goal position - object position (Insert, tool Reorient)."""
GOAL_ROTATION_ERROR = slice(169, 173)
"""Goal quaternion * conj(object quaternion) (Insert, tool Reorient)."""


def floats(v) -> list[float]:
    """The entries of a short vector (array, list or tuple) as Python floats, for plain float arithmetic:
    numpy's per-call overhead would be most of the cost of three- and four-element maths, run every env step."""
    return v.tolist() if isinstance(v, np.ndarray) else [float(x) for x in v]


def point_in_world(pose: list[float], p_BQ: list[float]) -> list[float]:
    """p_WQ of a point Q fixed in a body B, from B's pose [x, y, z, qw, qx, qy, qz] (e.g. an observation's
    ``PALM_POSE`` entries), as floats: p_WB + R(q) p_BQ, with R(q) v = v + 2 w (u x v) + 2 u x (u x v) for
    q = [w, u], in float arithmetic."""
    x, y, z, w, ux, uy, uz = pose
    vx, vy, vz = p_BQ
    tx, ty, tz = 2.0 * (uy * vz - uz * vy), 2.0 * (uz * vx - ux * vz), 2.0 * (ux * vy - uy * vx)  # 2 u x v
    return [x + vx + w * tx + uy * tz - uz * ty, y + vy + w * ty + uz * tx - ux * tz,
            z + vz + w * tz + ux * ty - uy * tx]


def quat_product(a, b) -> list[float]:
    """Hamilton product of quaternions [w, x, y, z] (short sequences of floats), as a list of floats."""
    a0, a1, a2, a3 = a
    b0, b1, b2, b3 = b
    return [a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3, a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1, a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0]


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions [w, x, y, z] (see :func:`quat_product`)."""
    return np.array(quat_product(floats(a), floats(b)))


def rotation_matrix(q_wxyz) -> np.ndarray:
    """The 3x3 rotation matrix of quaternion [w, x, y, z] (normalized first), e.g. an observed pose's (R_WB)."""
    w, x, y, z = np.asarray(q_wxyz, dtype=float) / np.linalg.norm(q_wxyz)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def quat_conjugate(q) -> list[float]:
    """[w, -x, -y, -z] of a quaternion [w, x, y, z], as a list of floats."""
    w, x, y, z = floats(q)
    return [w, -x, -y, -z]


def pose_vector(X) -> np.ndarray:
    """[x, y, z, qw, qx, qy, qz] of a RigidTransform, with qw >= 0."""
    out = np.empty(7)
    _write_pose(out, 0, X)
    return out


def _write_pose(out: np.ndarray, start: int, X) -> None:
    """Writes :func:`pose_vector` of ``X`` into ``out[start:start + 7]``."""
    q = X.rotation().ToQuaternion().wxyz()
    out[start:start + 3] = X.translation()
    out[start + 3:start + 7] = q if q[0] >= 0 else -q
