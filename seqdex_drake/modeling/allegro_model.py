"""The Allegro right hand (v4) model, built from published dimensions and the release's joint limits.

Frame convention (see `seqdex_drake.robots.allegro`): `hand_root` is at the centre of the wrist mounting plate,
+z toward the fingertips, +x the palm normal out of the palm (the side the fingers curl toward), +y from the ring
finger toward the index finger, so the thumb is on the +y side. The `palm` body is welded to `hand_root` with the
identity pose and fills the box x in [-0.0204, 0.0204], y in [-0.0565, 0.0565], z in [0, 0.095].

Fingers (index, middle, ring): bases on the palm top (z = 0.095, x = 0) at y = +0.0435, 0, -0.0435 (the
published 43.5 mm pitch). Joint 0 of each finger abducts about +x (a positive angle tilts the finger toward -y);
joints 1-3 flex about +y, so positive angles curl the finger toward +x. Published link lengths: 0.0164 m
(abduction base), 0.054 m (proximal), 0.0384 m (middle); the fingertip frame is 0.060 m beyond joint 3.

Thumb: joint 12 sits inside the palm's lower +y edge and rotates the thumb about -z (along the palm length):
at q12 = 0 the thumb's rotator arm points along +y, beside the palm, and increasing q12 swings it in front of
the palm (+x). Joints 13-15 flex the thumb about the rotator arm's direction, curling it across the front of the
palm toward the fingers. Segments: 0.0177 m and 0.0514 m, tip 0.075 m beyond joint 15.

Contact geometry, chosen for fast and stable point contact: a box palm, capsules of radius 0.0098 m (the 19.6 mm
finger width) for the phalanges, and a sphere of radius 0.012 m CENTRED on each fingertip frame (so a fingertip
frame is 0.012 m from the surface it touches). All hand collision geometries carry Coulomb friction 1.0 (static
and dynamic), enough to hold plastic blocks; Drake's default point stiffness and dissipation are kept.

Masses: about 1.08 kg in all (the published hand weight), split as a 0.42 kg palm, 0.16 kg per finger and
0.175 kg for the thumb, each link a uniform solid box or cylinder.

Self-collision: Drake filters parent/child pairs (so the palm never collides with the finger bases or the thumb
rotator, which sits in the palm edge). One filter group is added: the thumb rotator and the two short thumb
links after it form a compact knuckle (see THUMB_KNUCKLE_GROUP). Everything else may collide. The open, pinch
and curled (75% flexion) configurations are collision-free; at the flexion upper limits the fingertips reach
into the palm box, so there the palm contact, not the joint limit, stops the fingers (as on the real hand, whose
limits also allow more curl than the palm leaves room for).
"""

import numpy as np

from seqdex_drake.modeling.urdf_builder import (
    Box,
    Capsule,
    Pose,
    Sphere,
    UrdfBuilder,
    box_inertia,
    pose_along_segment,
    rod_inertia,
)
from seqdex_drake.robots.allegro import (
    ALLEGRO_EFFORT_MAX,
    ALLEGRO_JOINT_NAMES,
    ALLEGRO_MODEL_NAME,
    ALLEGRO_Q_MAX,
    ALLEGRO_Q_MIN,
    ALLEGRO_V_MAX,
    FINGER_NAMES,
    FINGERTIP_FRAMES,
    FINGERTIP_RADIUS,
    HAND_ROOT_FRAME,
    PALM_BODY,
)

PALM_SIZE = (0.0408, 0.113, 0.095)
"""Palm box (thickness along x, width along y, length along z) [m]."""

FINGER_BASE_Y = (0.0435, 0.0, -0.0435)
"""y of the index, middle and ring finger bases on the palm top [m]."""

FINGER_SEGMENTS = (0.0164, 0.054, 0.0384)
"""Distances joint 0 -> 1 (abduction base), 1 -> 2 (proximal) and 2 -> 3 (middle phalanx) [m]."""

FINGER_TIP_OFFSET = 0.060
"""Fingertip frame beyond joint 3 along the distal phalanx [m] (release value)."""

THUMB_ROTATOR_ORIGIN = (0.005, 0.045, 0.025)
"""Joint 12 in `hand_root` [m]: inside the palm's lower +y edge, 25 mm above the wrist plate."""

THUMB_ROTATOR_ARM = (0.0, 0.035, 0.010)
"""Joint 13 in the thumb rotator's frame [m] (at q12 = 0 this is along +y and slightly up)."""

THUMB_SEGMENTS = (0.0177, 0.0514)
"""Distances joint 13 -> 14 and 14 -> 15 [m]."""

THUMB_TIP_OFFSET = 0.075
"""Thumb tip frame beyond joint 15 [m] (release value)."""

PHALANX_RADIUS = 0.0098
"""Capsule radius of the phalanges [m] (half the 19.6 mm finger width)."""

THUMB_ROTATOR_RADIUS = 0.012
"""Capsule radius of the thumb rotator arm [m]."""

THUMB_KNUCKLE_GROUP = "thumb_knuckle"
"""Collision filter group of the thumb rotator and the two short links after it. Joints 13 and 14 are only
17.7 mm apart, so the rotator (adjacent to link 1 only) would otherwise touch link 2 in every configuration; on
the real hand these parts form one compact knuckle."""

PALM_MASS = 0.42
FINGER_LINK_MASSES = (0.02, 0.065, 0.04, 0.035)
THUMB_LINK_MASSES = (0.06, 0.02, 0.05, 0.045)

HAND_FRICTION = 1.0
"""Static and dynamic Coulomb friction of every hand collision geometry."""

JOINT_DAMPING = 0.01
"""Viscous joint damping [N m s/rad]: 1% of the release's hand PD damping (kd = 1), a small numerical cushion."""

PALM_GREY = (0.2, 0.2, 0.2, 1.0)
PHALANX_BLACK = (0.06, 0.06, 0.06, 1.0)
BASE_GREY = (0.3, 0.3, 0.3, 1.0)
FINGERTIP_WHITE = (0.95, 0.95, 0.95, 1.0)


def _add_rod_link(builder: UrdfBuilder, link: str, mass: float, radius: float, p_A, p_B, rgba) -> None:
    """Adds a link whose mass is a uniform rod from A to B and whose geometry is the matching capsule."""
    p_com, I_com = rod_inertia(mass, radius, p_A, p_B)
    builder.add_link(link, mass, p_com, I_com)
    pose, length = pose_along_segment(p_A, p_B)
    builder.add_shape(link, link, Capsule(radius, length), pose, rgba, friction=HAND_FRICTION)


def _add_distal(builder: UrdfBuilder, link: str, mass: float, tip_offset: float, tip_frame: str) -> None:
    """Adds a distal phalanx with its fingertip sphere and the massless fingertip frame at the sphere centre."""
    _add_rod_link(builder, link, mass, PHALANX_RADIUS, (0.0, 0.0, 0.0), (0.0, 0.0, tip_offset), PHALANX_BLACK)
    builder.add_shape(
        link,
        f"{link}_fingertip",
        Sphere(FINGERTIP_RADIUS),
        Pose((0.0, 0.0, tip_offset)),
        FINGERTIP_WHITE,
        friction=HAND_FRICTION,
    )
    builder.add_link(tip_frame)
    builder.add_fixed_joint(f"{tip_frame}_joint", link, tip_frame, Pose((0.0, 0.0, tip_offset)))


def _add_joint(builder: UrdfBuilder, index: int, parent: str, child: str, xyz, axis) -> None:
    builder.add_revolute_joint(
        ALLEGRO_JOINT_NAMES[index],
        parent,
        child,
        Pose(tuple(xyz)),
        axis,
        ALLEGRO_Q_MIN[index],
        ALLEGRO_Q_MAX[index],
        ALLEGRO_EFFORT_MAX[index],
        ALLEGRO_V_MAX[index],
        JOINT_DAMPING,
    )


def _add_finger(builder: UrdfBuilder, finger_index: int) -> None:
    """Adds index (0), middle (1) or ring (2): abduction base, three phalanges, fingertip frame."""
    finger = FINGER_NAMES[finger_index]
    links = [f"{finger}_link_{k}" for k in range(4)]
    first_joint = 4 * finger_index
    base_length, proximal_length, middle_length = FINGER_SEGMENTS
    builder.comment(f"{finger} finger: joints {first_joint}-{first_joint + 3}.")

    base_size = (2 * PHALANX_RADIUS, 2 * PHALANX_RADIUS, base_length)
    builder.add_link(
        links[0], FINGER_LINK_MASSES[0], (0.0, 0.0, base_length / 2), box_inertia(FINGER_LINK_MASSES[0], base_size)
    )
    builder.add_shape(
        links[0], links[0], Box(base_size), Pose((0.0, 0.0, base_length / 2)), BASE_GREY, friction=HAND_FRICTION
    )
    for k, length in ((1, proximal_length), (2, middle_length)):
        _add_rod_link(
            builder,
            links[k],
            FINGER_LINK_MASSES[k],
            PHALANX_RADIUS,
            (0.0, 0.0, 0.0),
            (0.0, 0.0, length),
            PHALANX_BLACK,
        )
    _add_distal(builder, links[3], FINGER_LINK_MASSES[3], FINGER_TIP_OFFSET, FINGERTIP_FRAMES[finger_index])

    palm_top = PALM_SIZE[2]
    _add_joint(builder, first_joint, PALM_BODY, links[0], (0.0, FINGER_BASE_Y[finger_index], palm_top), (1, 0, 0))
    _add_joint(builder, first_joint + 1, links[0], links[1], (0.0, 0.0, base_length), (0, 1, 0))
    _add_joint(builder, first_joint + 2, links[1], links[2], (0.0, 0.0, proximal_length), (0, 1, 0))
    _add_joint(builder, first_joint + 3, links[2], links[3], (0.0, 0.0, middle_length), (0, 1, 0))


def _add_thumb(builder: UrdfBuilder) -> None:
    """Adds the thumb: rotator (joint 12) and three flexion joints (13-15)."""
    links = [f"thumb_link_{k}" for k in range(4)]
    builder.comment("thumb: joints 12-15; joint 12 swings the thumb in front of the palm, 13-15 flex it.")
    _add_rod_link(
        builder,
        links[0],
        THUMB_LINK_MASSES[0],
        THUMB_ROTATOR_RADIUS,
        (0.0, 0.0, 0.0),
        THUMB_ROTATOR_ARM,
        BASE_GREY,
    )
    for k, length in ((1, THUMB_SEGMENTS[0]), (2, THUMB_SEGMENTS[1])):
        _add_rod_link(
            builder,
            links[k],
            THUMB_LINK_MASSES[k],
            PHALANX_RADIUS,
            (0.0, 0.0, 0.0),
            (0.0, 0.0, length),
            PHALANX_BLACK,
        )
    _add_distal(builder, links[3], THUMB_LINK_MASSES[3], THUMB_TIP_OFFSET, FINGERTIP_FRAMES[3])

    _add_joint(builder, 12, PALM_BODY, links[0], THUMB_ROTATOR_ORIGIN, (0, 0, -1))
    _add_joint(builder, 13, links[0], links[1], THUMB_ROTATOR_ARM, (0, 1, 0))
    _add_joint(builder, 14, links[1], links[2], (0.0, 0.0, THUMB_SEGMENTS[0]), (0, 1, 0))
    _add_joint(builder, 15, links[2], links[3], (0.0, 0.0, THUMB_SEGMENTS[1]), (0, 1, 0))
    builder.add_collision_filter_group(THUMB_KNUCKLE_GROUP, links[:3], (THUMB_KNUCKLE_GROUP,))


def hand_mass() -> float:
    """Total mass of the hand model [kg]."""
    return PALM_MASS + 3 * sum(FINGER_LINK_MASSES) + sum(THUMB_LINK_MASSES)


def build_allegro_right_urdf() -> str:
    """Returns the text of `models/allegro/allegro_right.urdf`."""
    header = (
        " Allegro right hand (v4) for seqdex-drake. GENERATED by scripts/generate_robot_models.py from\n"
        "     seqdex_drake/modeling/allegro_model.py (published link lengths and the release's joint limits);\n"
        "     do not edit by hand. hand_root: wrist plate centre, +z toward the fingertips, +x palm normal out\n"
        "     of the palm, +y from ring toward index (thumb side). Joints joint_0..joint_15 = index, middle,\n"
        "     ring, thumb. Fingertip frames are at the centres of the 0.012 m fingertip spheres. "
    )
    builder = UrdfBuilder(ALLEGRO_MODEL_NAME, header)
    builder.add_link(HAND_ROOT_FRAME)
    palm_centre = (0.0, 0.0, PALM_SIZE[2] / 2)
    builder.add_link(PALM_BODY, PALM_MASS, palm_centre, box_inertia(PALM_MASS, PALM_SIZE))
    builder.add_shape(PALM_BODY, PALM_BODY, Box(PALM_SIZE), Pose(palm_centre), PALM_GREY, friction=HAND_FRICTION)
    builder.add_fixed_joint("palm_joint", HAND_ROOT_FRAME, PALM_BODY, Pose())
    for finger_index in range(3):
        _add_finger(builder, finger_index)
    _add_thumb(builder)
    return builder.to_string()


def fingertip_offsets() -> np.ndarray:
    """Fingertip-frame offsets beyond the last flexion axis, canonical finger order [m]."""
    return np.array([FINGER_TIP_OFFSET] * 3 + [THUMB_TIP_OFFSET])
