"""The Franka Panda arm model, built from published data.

Kinematics: Franka Emika's published modified (Craig) Denavit-Hartenberg table. Joint i's frame is reached from
link i-1's frame by Rot_x(alpha_i) Trans_x(a_i) Trans_z(d_i), then rotates about its z axis by q_i; the flange
(`panda_link8`) is 0.107 m along link 7's z axis. At q = 0 the flange origin is at (0.088, 0, 0.926) m in the base
frame with its z axis pointing down.

Dynamics: link masses, centres of mass and rotational inertias (about the centre of mass, in the DH link
frames) of links 1-7 from the feasible parameter set identified by C. Gaz, M. Cognetti, A. Oliva, P. Robuffo
Giordano and A. De Luca, "Dynamic Identification of the Franka Emika Panda Robot With Retrieval of Feasible
Parameters Using Penalty-Based Optimization", IEEE RA-L 4(4), 2019. Every tensor satisfies the principal-moment
triangle inequality as published (link 2 by the smallest margin, about 2e-6 kg m^2), so none was changed. Link 1's
published Ixx and Iyy (about 0.70 kg m^2) are large for its mass but have no effect: link 1 only ever rotates
about its z axis (Izz = 0.009 kg m^2). Link 0 was not identified; it is welded, and gets 2.0 kg (the ~18 kg
datasheet arm weight minus the identified 16.1 kg) spread as a solid cylinder matching its collision shape.

Geometry: capsules sized to the real links (about 0.06 m radius at the shoulder and upper arm, 0.05 m at the
forearm and wrist), placed by end points written in the base frame at q = 0 and converted to each link frame.
Visual geometry repeats the collision shapes in Franka white with grey joint housings.
"""

import numpy as np

from seqdex_drake.modeling.urdf_builder import (
    Capsule,
    Cylinder,
    Pose,
    UrdfBuilder,
    cylinder_inertia,
    inertia_from_six,
    pose_along_segment,
    rotation_to_rpy,
)
from seqdex_drake.robots.franka import (
    BASE_FRAME,
    FLANGE_FRAME,
    FLANGE_OFFSET,
    FRANKA_EFFORT_MAX,
    FRANKA_JOINT_NAMES,
    FRANKA_MODEL_NAME,
    FRANKA_Q_MAX,
    FRANKA_Q_MIN,
    FRANKA_V_MAX,
)

# Modified DH parameters of joints 1..7: (a_{i-1} [m], d_i [m], alpha_{i-1} [rad]).
DH_A = (0.0, 0.0, 0.0, 0.0825, -0.0825, 0.0, 0.088)
DH_D = (0.333, 0.0, 0.316, 0.0, 0.384, 0.0, 0.0)
DH_ALPHA = (0.0, -np.pi / 2, np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, np.pi / 2)

JOINT_DAMPING = 0.1
"""Viscous joint damping [N m s/rad]: small compared with the arm's PD damping (kd 80), it only takes the edge off
unactuated motion; the identified viscous friction of the real joints is of the same order."""

# Gaz et al. (2019), links 1..7: mass [kg], CoM in the link frame [m], (Ixx, Ixy, Ixz, Iyy, Iyz, Izz) [kg m^2].
IDENTIFIED_MASS = (4.970684, 0.646926, 3.228604, 3.587895, 1.225946, 1.666555, 0.735522)
IDENTIFIED_COM = (
    (3.875e-03, 2.081e-03, -4.762e-02),
    (-3.141e-03, -2.872e-02, 3.495e-03),
    (2.7518e-02, 3.9252e-02, -6.6502e-02),
    (-5.317e-02, 1.04419e-01, 2.7454e-02),
    (-1.1953e-02, 4.1065e-02, -3.8437e-02),
    (6.0149e-02, -1.4117e-02, -1.0517e-02),
    (1.0517e-02, -4.252e-03, 6.1597e-02),
)
IDENTIFIED_INERTIA = (
    (7.0337e-01, -1.39e-04, 6.772e-03, 7.0661e-01, 1.9169e-02, 9.117e-03),
    (7.962e-03, -3.925e-03, 1.0254e-02, 2.811e-02, 7.04e-04, 2.5995e-02),
    (3.7242e-02, -4.761e-03, -1.1396e-02, 3.6155e-02, -1.2805e-02, 1.083e-02),
    (2.5853e-02, 7.796e-03, -1.332e-03, 1.9552e-02, 8.641e-03, 2.8323e-02),
    (3.5549e-02, -2.117e-03, -4.037e-03, 2.9474e-02, 2.29e-04, 8.627e-03),
    (1.964e-03, 1.09e-04, -1.158e-03, 4.354e-03, 3.41e-04, 5.433e-03),
    (1.2516e-02, -4.28e-04, -1.196e-03, 1.0027e-02, -7.41e-04, 4.815e-03),
)

BASE_MASS = 2.0
"""Mass of the (welded) base link [kg]; see the module docstring."""

FRANKA_WHITE = (0.95, 0.95, 0.95, 1.0)
FRANKA_GREY = (0.35, 0.35, 0.37, 1.0)

# Base cylinder in the base frame: axis end points [m] and radius [m].
BASE_CYLINDER = ((-0.025, 0.0, 0.0), (-0.025, 0.0, 0.13), 0.09)

# Link capsules as (link index, name, end point A, end point B, radius, colour), with the end points written in
# the base frame at q = 0 (arm straight up, flange pointing down at (0.088, 0, 0.926)).
LINK_CAPSULES = (
    (1, "column", (0.0, 0.0, 0.19), (0.0, 0.0, 0.30), 0.06, FRANKA_WHITE),
    (2, "shoulder", (0.0, -0.05, 0.333), (0.0, 0.05, 0.333), 0.06, FRANKA_GREY),
    (2, "upper_arm", (0.0, 0.0, 0.333), (0.0, 0.0, 0.46), 0.06, FRANKA_WHITE),
    (3, "upper_arm", (0.0, 0.0, 0.46), (0.0, 0.0, 0.60), 0.06, FRANKA_WHITE),
    (3, "elbow", (0.0825, -0.05, 0.649), (0.0825, 0.05, 0.649), 0.055, FRANKA_GREY),
    (4, "knee", (0.07, 0.0, 0.67), (0.01, 0.0, 0.78), 0.055, FRANKA_WHITE),
    (5, "forearm", (0.0, 0.0, 0.80), (0.0, 0.0, 0.92), 0.05, FRANKA_WHITE),
    (6, "wrist", (0.0, -0.045, 1.033), (0.0, 0.045, 1.033), 0.05, FRANKA_GREY),
    (6, "wrist_arm", (0.0, 0.0, 1.033), (0.088, 0.0, 1.033), 0.045, FRANKA_WHITE),
    (7, "hand_link", (0.088, 0.0, 1.02), (0.088, 0.0, 0.975), 0.045, FRANKA_WHITE),
)

# The flange disc (ISO 9409-1-50: 63 mm diameter), visual only, in the base frame at q = 0.
FLANGE_DISC = ((0.088, 0.0, 0.936), (0.088, 0.0, 0.926), 0.0315)


def rot_x(angle: float) -> np.ndarray:
    """Rotation matrix about x."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def joint_pose_in_parent(index: int) -> tuple[np.ndarray, np.ndarray]:
    """Pose (R_PJ, p_PoJo_P) of joint `index` (0-based) in its parent link at q = 0, from the DH table."""
    alpha, a, d = DH_ALPHA[index], DH_A[index], DH_D[index]
    R_PJ = rot_x(alpha)
    p_PoJo_P = np.array([a, 0.0, 0.0]) + R_PJ @ np.array([0.0, 0.0, d])
    return R_PJ, p_PoJo_P


def link_poses_at_zero() -> list[tuple[np.ndarray, np.ndarray]]:
    """(R_BL, p_BoLo_B) of links 0..7 in the base frame at q = 0."""
    poses = [(np.eye(3), np.zeros(3))]
    for index in range(7):
        R_BP, p_BoPo_B = poses[-1]
        R_PJ, p_PoJo_P = joint_pose_in_parent(index)
        poses.append((R_BP @ R_PJ, p_BoPo_B + R_BP @ p_PoJo_P))
    return poses


def flange_position_at_zero() -> np.ndarray:
    """p_BoFo_B of the flange at q = 0 (should be (0.088, 0, 0.926))."""
    R_B7, p_Bo7o_B = link_poses_at_zero()[7]
    return p_Bo7o_B + R_B7 @ np.array([0.0, 0.0, FLANGE_OFFSET])


def _segment_in_link(link_pose, p_A_B, p_B_B) -> tuple[Pose, float]:
    """Converts base-frame end points at q = 0 into a pose and length in the link frame."""
    R_BL, p_BoLo_B = link_pose
    p_A_L = R_BL.T @ (np.asarray(p_A_B) - p_BoLo_B)
    p_B_L = R_BL.T @ (np.asarray(p_B_B) - p_BoLo_B)
    return pose_along_segment(p_A_L, p_B_L)


def build_panda_urdf() -> str:
    """Returns the text of `models/franka/panda_arm.urdf`."""
    header = (
        " Franka Emika Panda arm for seqdex-drake. GENERATED by scripts/generate_robot_models.py from\n"
        "     seqdex_drake/modeling/franka_model.py (published DH table, joint limits and the dynamic\n"
        "     identification of Gaz et al., RA-L 2019); do not edit by hand. Links panda_link0..7 follow the\n"
        "     modified DH frames; panda_link8 is the massless flange, 0.107 m along link 7's z axis. "
    )
    builder = UrdfBuilder(FRANKA_MODEL_NAME, header)
    link_poses = link_poses_at_zero()
    link_names = [BASE_FRAME] + [f"panda_link{i}" for i in range(1, 8)]

    base_start, base_end, base_radius = BASE_CYLINDER
    base_pose, base_length = pose_along_segment(base_start, base_end)
    builder.comment("Base: not identified; a plausible mass as a solid cylinder matching its shape.")
    builder.add_link(BASE_FRAME, BASE_MASS, base_pose.xyz, cylinder_inertia(BASE_MASS, base_radius, base_length))
    builder.add_shape(BASE_FRAME, "base", Cylinder(base_radius, base_length), base_pose, FRANKA_WHITE)

    for index in range(7):
        link = link_names[index + 1]
        builder.comment(f"{link}: inertial parameters from Gaz et al. (2019), unchanged.")
        builder.add_link(
            link,
            IDENTIFIED_MASS[index],
            IDENTIFIED_COM[index],
            inertia_from_six(*IDENTIFIED_INERTIA[index]),
        )
        for link_index, name, p_A, p_B, radius, rgba in LINK_CAPSULES:
            if link_index != index + 1:
                continue
            pose, length = _segment_in_link(link_poses[link_index], p_A, p_B)
            builder.add_shape(link, f"{link}_{name}", Capsule(radius, length), pose, rgba)
    disc_start, disc_end, disc_radius = FLANGE_DISC
    disc_pose, disc_length = _segment_in_link(link_poses[7], disc_start, disc_end)
    builder.add_shape(
        "panda_link7", "panda_link7_flange", Cylinder(disc_radius, disc_length), disc_pose, FRANKA_GREY, False
    )
    builder.add_link(FLANGE_FRAME)

    for index, joint in enumerate(FRANKA_JOINT_NAMES):
        R_PJ, p_PoJo_P = joint_pose_in_parent(index)
        builder.add_revolute_joint(
            joint,
            link_names[index],
            link_names[index + 1],
            Pose(tuple(p_PoJo_P), rotation_to_rpy(R_PJ)),
            (0.0, 0.0, 1.0),
            FRANKA_Q_MIN[index],
            FRANKA_Q_MAX[index],
            FRANKA_EFFORT_MAX[index],
            FRANKA_V_MAX[index],
            JOINT_DAMPING,
        )
    builder.add_fixed_joint(
        "panda_joint8", "panda_link7", FLANGE_FRAME, Pose((0.0, 0.0, FLANGE_OFFSET), (0.0, 0.0, 0.0))
    )
    return builder.to_string()
