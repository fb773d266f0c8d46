"""A small, deterministic URDF writer with the Drake extensions our robot models use.

Shapes, inertias and poses are plain numbers; `UrdfBuilder` turns them into a URDF document whose text depends
only on those numbers (fixed float formatting, insertion-ordered attributes), so regenerating a model reproduces
the committed file byte for byte.

Drake extensions used: `<drake:capsule>` geometry, `<drake:proximity_properties>` (friction) and
`<drake:collision_filter_group>`. Actuators come from standard `<transmission>` elements.
"""

import dataclasses
import xml.etree.ElementTree as ET

import numpy as np
from pydrake.math import RollPitchYaw, RotationMatrix

DRAKE_XMLNS = "http://drake.mit.edu"


def format_number(value: float) -> str:
    """Formats a float with 9 significant digits; values within 1e-12 of zero print as 0."""
    value = float(value)
    if abs(value) < 1e-12:
        return "0"
    return format(value, ".9g")


def format_vector(values) -> str:
    """Formats a sequence of floats separated by single spaces."""
    return " ".join(format_number(v) for v in values)


@dataclasses.dataclass(frozen=True)
class Box:
    """A box with full side lengths `size` = (x, y, z) [m]."""

    size: tuple


@dataclasses.dataclass(frozen=True)
class Sphere:
    """A sphere of the given radius [m]."""

    radius: float


@dataclasses.dataclass(frozen=True)
class Cylinder:
    """A cylinder along its frame's z axis; `length` is the full height [m]."""

    radius: float
    length: float


@dataclasses.dataclass(frozen=True)
class Capsule:
    """A Drake capsule along its frame's z axis; `length` excludes the two hemispherical caps [m]."""

    radius: float
    length: float


@dataclasses.dataclass(frozen=True)
class Pose:
    """A URDF origin: translation `xyz` [m] and roll-pitch-yaw `rpy` [rad] of a child frame in its parent."""

    xyz: tuple = (0.0, 0.0, 0.0)
    rpy: tuple = (0.0, 0.0, 0.0)


def pose_along_segment(p_A, p_B) -> tuple[Pose, float]:
    """Returns the pose of a frame centred between points A and B with z along B - A, and |B - A|.

    Used to place capsules and cylinders (shapes symmetric about their centre) by their end points. Along
    +-z the frame keeps the parent's axes; otherwise Drake's deterministic `RotationMatrix.MakeFromOneVector`
    picks the x axis.
    """
    p_A = np.asarray(p_A, dtype=float)
    p_B = np.asarray(p_B, dtype=float)
    direction = p_B - p_A
    length = float(np.linalg.norm(direction))
    unit = direction / length
    if abs(abs(unit[2]) - 1.0) < 1e-12:
        # Along +z or -z: the shapes we place this way are symmetric under a flip, so keep the link's axes.
        rpy = np.zeros(3)
    else:
        rpy = RollPitchYaw(RotationMatrix.MakeFromOneVector(unit, 2)).vector()
    return Pose(tuple((p_A + p_B) / 2.0), tuple(rpy)), length


def rotation_to_rpy(R: np.ndarray) -> tuple:
    """Roll-pitch-yaw [rad] of a 3x3 rotation matrix."""
    return tuple(RollPitchYaw(RotationMatrix(np.asarray(R, dtype=float))).vector())


def box_inertia(mass: float, size) -> np.ndarray:
    """Rotational inertia about the centroid of a uniform solid box [kg m^2]."""
    x, y, z = size
    return mass / 12.0 * np.diag([y * y + z * z, x * x + z * z, x * x + y * y])


def cylinder_inertia(mass: float, radius: float, length: float) -> np.ndarray:
    """Rotational inertia about the centroid of a uniform solid cylinder along z [kg m^2]."""
    radial = mass * (3.0 * radius * radius + length * length) / 12.0
    return np.diag([radial, radial, mass * radius * radius / 2.0])


def sphere_inertia(mass: float, radius: float) -> np.ndarray:
    """Rotational inertia about the centre of a uniform solid sphere [kg m^2]."""
    return np.eye(3) * 0.4 * mass * radius * radius


def rod_inertia(mass: float, radius: float, p_A, p_B) -> tuple[np.ndarray, np.ndarray]:
    """Centre of mass and rotational inertia (about it, in the link frame) of a uniform solid cylinder
    running from point A to point B (both in the link frame)."""
    pose, length = pose_along_segment(p_A, p_B)
    R = RotationMatrix(RollPitchYaw(np.asarray(pose.rpy))).matrix()
    return np.asarray(pose.xyz), R @ cylinder_inertia(mass, radius, length) @ R.T


def inertia_from_six(ixx, ixy, ixz, iyy, iyz, izz) -> np.ndarray:
    """Builds the symmetric 3x3 inertia matrix from the six URDF components."""
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]], dtype=float)


class UrdfBuilder:
    """Accumulates links, joints, transmissions and filter groups, and serialises them.

    Args:
        robot_name: the URDF robot name (Drake's default model instance name).
        header: a comment placed at the top of the document (provenance, conventions).
    """

    def __init__(self, robot_name: str, header: str):
        self._robot = ET.Element("robot", {"name": robot_name, "xmlns:drake": DRAKE_XMLNS})
        self._robot.append(ET.Comment(header))
        self._links = {}

    def comment(self, text: str) -> None:
        """Adds a comment at the current position of the document."""
        self._robot.append(ET.Comment(f" {text} "))

    def add_link(self, name: str, mass: float | None = None, p_LoCm=(0.0, 0.0, 0.0), I_Cm=None) -> None:
        """Adds a link. Without `mass` the link is massless (only valid when it is welded to a massive body).

        Args:
            name: link name.
            mass: mass [kg].
            p_LoCm: centre of mass in the link frame [m].
            I_Cm: 3x3 rotational inertia about the centre of mass, expressed in the link frame [kg m^2].
        """
        link = ET.SubElement(self._robot, "link", {"name": name})
        self._links[name] = link
        if mass is None:
            return
        I_Cm = np.asarray(I_Cm, dtype=float)
        inertial = ET.SubElement(link, "inertial")
        ET.SubElement(inertial, "origin", {"xyz": format_vector(p_LoCm), "rpy": "0 0 0"})
        ET.SubElement(inertial, "mass", {"value": format_number(mass)})
        ET.SubElement(
            inertial,
            "inertia",
            {
                "ixx": format_number(I_Cm[0, 0]),
                "ixy": format_number(I_Cm[0, 1]),
                "ixz": format_number(I_Cm[0, 2]),
                "iyy": format_number(I_Cm[1, 1]),
                "iyz": format_number(I_Cm[1, 2]),
                "izz": format_number(I_Cm[2, 2]),
            },
        )

    @staticmethod
    def _add_geometry(parent: ET.Element, shape) -> None:
        geometry = ET.SubElement(parent, "geometry")
        if isinstance(shape, Box):
            ET.SubElement(geometry, "box", {"size": format_vector(shape.size)})
        elif isinstance(shape, Sphere):
            ET.SubElement(geometry, "sphere", {"radius": format_number(shape.radius)})
        elif isinstance(shape, Cylinder):
            attributes = {"radius": format_number(shape.radius), "length": format_number(shape.length)}
            ET.SubElement(geometry, "cylinder", attributes)
        elif isinstance(shape, Capsule):
            attributes = {"radius": format_number(shape.radius), "length": format_number(shape.length)}
            ET.SubElement(geometry, "drake:capsule", attributes)
        else:
            raise TypeError(f"Unsupported shape {shape!r}")

    @staticmethod
    def _add_origin(parent: ET.Element, pose: Pose) -> None:
        ET.SubElement(parent, "origin", {"xyz": format_vector(pose.xyz), "rpy": format_vector(pose.rpy)})

    def add_shape(
        self,
        link_name: str,
        name: str,
        shape,
        pose: Pose,
        rgba,
        collide: bool = True,
        friction: float | None = None,
    ) -> None:
        """Adds a visual and (optionally) an identical collision geometry to a link.

        Args:
            link_name: the link that owns the shape.
            name: base name; the elements are named `<name>_visual` and `<name>_collision`.
            shape: a Box, Sphere, Cylinder or Capsule.
            pose: pose of the shape frame in the link frame.
            rgba: visual colour.
            collide: whether to add the collision element.
            friction: if given, static and dynamic Coulomb friction written as Drake proximity properties;
                otherwise Drake's default friction applies.
        """
        link = self._links[link_name]
        visual = ET.SubElement(link, "visual", {"name": f"{name}_visual"})
        self._add_origin(visual, pose)
        self._add_geometry(visual, shape)
        material = ET.SubElement(visual, "material", {"name": f"{name}_material"})
        ET.SubElement(material, "color", {"rgba": format_vector(rgba)})
        if not collide:
            return
        collision = ET.SubElement(link, "collision", {"name": f"{name}_collision"})
        self._add_origin(collision, pose)
        self._add_geometry(collision, shape)
        if friction is not None:
            properties = ET.SubElement(collision, "drake:proximity_properties")
            ET.SubElement(properties, "drake:mu_dynamic", {"value": format_number(friction)})
            ET.SubElement(properties, "drake:mu_static", {"value": format_number(friction)})

    def add_revolute_joint(
        self,
        name: str,
        parent: str,
        child: str,
        pose: Pose,
        axis,
        lower: float,
        upper: float,
        effort: float,
        velocity: float,
        damping: float,
    ) -> None:
        """Adds a revolute joint with limits and viscous damping, and a transmission (hence an actuator)
        of the same name, whose effort limit Drake takes from the joint's `effort`."""
        joint = ET.SubElement(self._robot, "joint", {"name": name, "type": "revolute"})
        ET.SubElement(joint, "parent", {"link": parent})
        ET.SubElement(joint, "child", {"link": child})
        self._add_origin(joint, pose)
        ET.SubElement(joint, "axis", {"xyz": format_vector(axis)})
        limit = {
            "lower": format_number(lower),
            "upper": format_number(upper),
            "effort": format_number(effort),
            "velocity": format_number(velocity),
        }
        ET.SubElement(joint, "limit", limit)
        ET.SubElement(joint, "dynamics", {"damping": format_number(damping), "friction": "0"})
        transmission = ET.SubElement(self._robot, "transmission", {"name": f"{name}_transmission"})
        ET.SubElement(transmission, "type").text = "transmission_interface/SimpleTransmission"
        transmission_joint = ET.SubElement(transmission, "joint", {"name": name})
        interface = ET.SubElement(transmission_joint, "hardwareInterface")
        interface.text = "hardware_interface/EffortJointInterface"
        actuator = ET.SubElement(transmission, "actuator", {"name": name})
        ET.SubElement(actuator, "mechanicalReduction").text = "1"

    def add_fixed_joint(self, name: str, parent: str, child: str, pose: Pose) -> None:
        """Adds a weld between two links."""
        joint = ET.SubElement(self._robot, "joint", {"name": name, "type": "fixed"})
        ET.SubElement(joint, "parent", {"link": parent})
        ET.SubElement(joint, "child", {"link": child})
        self._add_origin(joint, pose)

    def add_collision_filter_group(self, name: str, members, ignored_groups) -> None:
        """Adds a Drake collision filter group; collisions between its members and the members of each
        group in `ignored_groups` (which may include `name` itself) are filtered."""
        group = ET.SubElement(self._robot, "drake:collision_filter_group", {"name": name})
        for member in members:
            ET.SubElement(group, "drake:member", {"link": member})
        for ignored in ignored_groups:
            ET.SubElement(group, "drake:ignored_collision_filter_group", {"name": ignored})

    def to_string(self) -> str:
        """Serialises the document (2-space indentation, trailing newline)."""
        tree = ET.ElementTree(self._robot)
        ET.indent(tree, space="  ")
        body = ET.tostring(self._robot, encoding="unicode")
        return '<?xml version="1.0"?>\n' + body + "\n"
