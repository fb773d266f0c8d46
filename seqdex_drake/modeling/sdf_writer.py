"""SDFormat writing for generated models: inertial properties, visuals, collisions, Drake proximity properties.

The writer emits a fixed layout with fixed float formats so that regenerated files are byte-identical. Only
the subset of SDFormat that our generated models need is covered: one model, links with an inertial, visuals
and collisions whose geometry is a box, a cylinder or a mesh (optionally `drake:declare_convex`), and
Drake's `drake:proximity_properties` (friction, hydroelastic compliance).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import trimesh

DRAKE_NAMESPACE = "http://drake.mit.edu"


@dataclass(frozen=True)
class Inertial:
    """Mass properties of a rigid body, expressed in its link frame.

    Attributes:
        mass: kg.
        center_of_mass: (3,) position of the centre of mass in the link frame (m).
        inertia: (3, 3) rotational inertia about the centre of mass, link-frame axes (kg m^2).
    """

    mass: float
    center_of_mass: np.ndarray
    inertia: np.ndarray


def inertial_from_mesh(mesh: trimesh.Trimesh, density: float) -> Inertial:
    """Mass properties of a closed mesh of uniform density (the mesh's true solid volume times density).

    Args:
        mesh: a watertight triangle mesh with outward-facing triangles.
        density: kg/m^3.
    """
    if not mesh.is_watertight:
        raise ValueError("inertial_from_mesh needs a watertight mesh")
    unit = trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces, process=False)
    unit.density = 1.0
    volume = float(unit.volume)
    if volume <= 0.0:
        raise ValueError(f"mesh has non-positive volume {volume}; are its faces inverted?")
    return Inertial(
        mass=density * volume,
        center_of_mass=np.asarray(unit.center_mass, dtype=float),
        inertia=density * np.asarray(unit.moment_inertia, dtype=float),
    )


def box_inertial(size: Sequence[float], density: float, center: Sequence[float] = (0.0, 0.0, 0.0)) -> Inertial:
    """Mass properties of a solid axis-aligned box of uniform density centred at `center`."""
    a, b, c = (float(s) for s in size)
    mass = density * a * b * c
    inertia = mass / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    return Inertial(mass=mass, center_of_mass=np.asarray(center, dtype=float), inertia=inertia)


def combine_inertials(parts: Sequence[Inertial]) -> Inertial:
    """Mass properties of a body made of several disjoint parts (parallel-axis theorem)."""
    mass = sum(part.mass for part in parts)
    center = sum(part.mass * part.center_of_mass for part in parts) / mass
    inertia = np.zeros((3, 3))
    for part in parts:
        offset = part.center_of_mass - center
        inertia += part.inertia + part.mass * (offset @ offset * np.eye(3) - np.outer(offset, offset))
    return Inertial(mass=mass, center_of_mass=center, inertia=inertia)


@dataclass(frozen=True)
class ProximityProperties:
    """Drake proximity properties for one collision geometry.

    Attributes:
        mu_dynamic: Coulomb dynamic friction.
        mu_static: Coulomb static friction (used by continuous plants only; kept >= mu_dynamic).
        hydroelastic_modulus: Pa, used when the scene selects a hydroelastic contact model.
        compliant_hydroelastic: declare the geometry compliant-hydroelastic (ignored under point contact).
        hunt_crossley_dissipation: s/m; None leaves Drake's scene-wide default.
        point_contact_stiffness: N/m; None leaves the plant's penetration-allowance default.
    """

    mu_dynamic: float
    mu_static: float
    hydroelastic_modulus: float = 1.0e7
    compliant_hydroelastic: bool = True
    hunt_crossley_dissipation: float | None = None
    point_contact_stiffness: float | None = None


@dataclass(frozen=True)
class Geometry:
    """An SDFormat geometry: kind is "box" (size), "cylinder" (radius, length) or "mesh" (uri, convex)."""

    kind: str
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = 0.0
    length: float = 0.0
    uri: str = ""
    convex: bool = False


def box(size: Sequence[float]) -> Geometry:
    """A box geometry centred on its frame."""
    return Geometry(kind="box", size=tuple(float(s) for s in size))


def cylinder(radius: float, length: float) -> Geometry:
    """A cylinder geometry centred on its frame, axis along z."""
    return Geometry(kind="cylinder", radius=radius, length=length)


def mesh(uri: str, convex: bool = False) -> Geometry:
    """A mesh geometry; `convex=True` adds `drake:declare_convex` (Drake uses the hull of the vertices)."""
    return Geometry(kind="mesh", uri=uri, convex=convex)


@dataclass(frozen=True)
class Visual:
    """A visual element: name, geometry, RGBA diffuse colour and pose [x y z roll pitch yaw] in the link."""

    name: str
    geometry: Geometry
    rgba: tuple[float, float, float, float]
    pose: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Collision:
    """A collision element: name, geometry, proximity properties and pose [x y z roll pitch yaw]."""

    name: str
    geometry: Geometry
    properties: ProximityProperties
    pose: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Link:
    """A link with its inertial, visuals and collisions."""

    name: str
    inertial: Inertial
    visuals: Sequence[Visual] = field(default_factory=tuple)
    collisions: Sequence[Collision] = field(default_factory=tuple)


def _num(value: float) -> str:
    """Fixed, round-trippable float text (-0 written as 0)."""
    text = f"{float(value):.9g}"
    return "0" if text in ("-0", "0") else text


def _nums(values: Sequence[float]) -> str:
    """Space-separated `_num` texts."""
    return " ".join(_num(v) for v in values)


def _geometry_lines(geometry: Geometry) -> list[str]:
    """The <geometry> element of a visual or collision."""
    if geometry.kind == "box":
        body = [f"<box><size>{_nums(geometry.size)}</size></box>"]
    elif geometry.kind == "cylinder":
        body = [
            "<cylinder>",
            f"  <radius>{_num(geometry.radius)}</radius>",
            f"  <length>{_num(geometry.length)}</length>",
            "</cylinder>",
        ]
    elif geometry.kind == "mesh":
        convex = "<drake:declare_convex/>" if geometry.convex else ""
        body = [f"<mesh><uri>{geometry.uri}</uri>{convex}</mesh>"]
    else:
        raise ValueError(f"unknown geometry kind {geometry.kind!r}; expected box, cylinder or mesh")
    return ["<geometry>"] + ["  " + line for line in body] + ["</geometry>"]


def _proximity_lines(properties: ProximityProperties) -> list[str]:
    """The <drake:proximity_properties> element of a collision."""
    lines = [
        f"<drake:mu_dynamic>{_num(properties.mu_dynamic)}</drake:mu_dynamic>",
        f"<drake:mu_static>{_num(properties.mu_static)}</drake:mu_static>",
    ]
    if properties.compliant_hydroelastic:
        lines.append("<drake:compliant_hydroelastic/>")
    lines.append(f"<drake:hydroelastic_modulus>{_num(properties.hydroelastic_modulus)}</drake:hydroelastic_modulus>")
    if properties.hunt_crossley_dissipation is not None:
        value = _num(properties.hunt_crossley_dissipation)
        lines.append(f"<drake:hunt_crossley_dissipation>{value}</drake:hunt_crossley_dissipation>")
    if properties.point_contact_stiffness is not None:
        value = _num(properties.point_contact_stiffness)
        lines.append(f"<drake:point_contact_stiffness>{value}</drake:point_contact_stiffness>")
    return ["<drake:proximity_properties>"] + ["  " + line for line in lines] + ["</drake:proximity_properties>"]


def _indent(lines: list[str], depth: int) -> list[str]:
    """Indents lines by two spaces per depth level."""
    return ["  " * depth + line for line in lines]


def _link_lines(link: Link) -> list[str]:
    """The <link> element: inertial, visuals, collisions."""
    inertial = link.inertial
    # Entries below 1e-12 kg m^2 (1e-9 m for the centre of mass) are round-off of symmetric shapes: write 0.
    i = np.where(np.abs(inertial.inertia) < 1e-12, 0.0, inertial.inertia)
    center = np.where(np.abs(inertial.center_of_mass) < 1e-9, 0.0, inertial.center_of_mass)
    lines = [
        f'<link name="{link.name}">',
        "  <inertial>",
        f"    <pose>{_nums(center)} 0 0 0</pose>",
        f"    <mass>{_num(inertial.mass)}</mass>",
        "    <inertia>",
        f"      <ixx>{_num(i[0, 0])}</ixx>",
        f"      <ixy>{_num(i[0, 1])}</ixy>",
        f"      <ixz>{_num(i[0, 2])}</ixz>",
        f"      <iyy>{_num(i[1, 1])}</iyy>",
        f"      <iyz>{_num(i[1, 2])}</iyz>",
        f"      <izz>{_num(i[2, 2])}</izz>",
        "    </inertia>",
        "  </inertial>",
    ]
    for visual in link.visuals:
        lines += _indent([f'<visual name="{visual.name}">', f"  <pose>{_nums(visual.pose)}</pose>"], 1)
        lines += _indent(_geometry_lines(visual.geometry), 2)
        lines += _indent(["<material>", f"  <diffuse>{_nums(visual.rgba)}</diffuse>", "</material>"], 2)
        lines += _indent(["</visual>"], 1)
    for collision in link.collisions:
        lines += _indent([f'<collision name="{collision.name}">', f"  <pose>{_nums(collision.pose)}</pose>"], 1)
        lines += _indent(_geometry_lines(collision.geometry), 2)
        lines += _indent(_proximity_lines(collision.properties), 2)
        lines += _indent(["</collision>"], 1)
    lines.append("</link>")
    return lines


def sdf_text(model_name: str, links: Sequence[Link], comment: str = "", static: bool = False) -> str:
    """Returns the SDFormat 1.9 text of a model with the given links."""
    lines = ['<?xml version="1.0"?>']
    lines.append("<!-- Generated by scripts/generate_assets.py (seqdex-drake); do not edit. -->")
    if comment:
        lines.append(f"<!-- {comment} -->")
    lines.append(f'<sdf version="1.9" xmlns:drake="{DRAKE_NAMESPACE}">')
    lines.append(f'  <model name="{model_name}">')
    if static:
        lines.append("    <static>true</static>")
    for link in links:
        lines += _indent(_link_lines(link), 2)
    lines += ["  </model>", "</sdf>"]
    return "\n".join(lines) + "\n"


def write_sdf(path: str, model_name: str, links: Sequence[Link], comment: str = "") -> None:
    """Writes an SDFormat model file (parent directories created)."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w", encoding="ascii", newline="\n") as stream:
        stream.write(sdf_text(model_name, links, comment))
