"""Tools for the tool-positioning task: hammer, spatula and ladle ("spoon"), built parametrically.

Each tool is modelled at the bounding box measured from the authors' release (long axis along y), with its
origin at the bounding-box centre:

* hammer, 0.034 x 0.378 x 0.141 m: a hickory handle along y and a steel head at the +y end spanning z, its
  round striking face at -z and a cross peen at +z.
* spatula, 0.167 x 0.724 x 0.080 m: a wooden handle along y near the top and a wide flat nylon blade at +y
  resting at the bottom, joined by an inclined neck.
* spoon (a ladle), 0.134 x 0.497 x 0.164 m: a hemispherical nylon bowl at +y and a cranked flat handle that
  rises to the top at -y.

The solid of each material is an exact manifold3d solid (materials do not overlap: the head wins over the handle
where they meet), giving one watertight visual OBJ per material with its own colour and the mass properties
from per-material densities. Collision geometry is a CoACD decomposition of the whole tool with a fixed seed.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import manifold3d
import numpy as np

from seqdex_drake.modeling import decomposition, sdf_writer

PACKAGE_NAME = "seqdex_models"
COACD_SEED = 0
TOOL_PROXIMITY = sdf_writer.ProximityProperties(mu_dynamic=0.6, mu_static=0.7, hydroelastic_modulus=1.0e7)
_SEGMENTS = 48


@dataclass(frozen=True)
class Material:
    """A material of a tool: name (also the visual's name), density (kg/m^3) and colour."""

    name: str
    density: float
    rgba: tuple[float, float, float, float]


@dataclass(frozen=True)
class ToolSpec:
    """One tool.

    Attributes:
        name: model name and directory name.
        description: what the shape is.
        bounding_box: (x, y, z) extent in metres (long axis along y), from the authors' release.
        materials: the materials, in order of precedence where their parts overlap.
        coacd_threshold: CoACD concavity threshold for the collision pieces.
    """

    name: str
    description: str
    bounding_box: tuple[float, float, float]
    materials: tuple[Material, ...]
    coacd_threshold: float


STEEL = Material("head", 7850.0, (0.45, 0.46, 0.50, 1.0))
HICKORY = Material("handle", 750.0, (0.72, 0.52, 0.30, 1.0))
NYLON_BLADE = Material("blade", 1150.0, (0.12, 0.12, 0.12, 1.0))
BEECH = Material("handle", 700.0, (0.78, 0.60, 0.40, 1.0))
NYLON = Material("body", 1150.0, (0.85, 0.25, 0.15, 1.0))

TOOL_SPECS: dict[str, ToolSpec] = {
    spec.name: spec
    for spec in (
        ToolSpec("hammer", "steel cross-peen head on a hickory handle", (0.034, 0.378, 0.141), (STEEL, HICKORY),
                 coacd_threshold=0.02),
        ToolSpec("spatula", "nylon turner blade on a beech handle", (0.167, 0.724, 0.080), (NYLON_BLADE, BEECH),
                 coacd_threshold=0.01),
        ToolSpec("spoon", "nylon ladle: hemispherical bowl and cranked handle", (0.134, 0.497, 0.164), (NYLON,),
                 coacd_threshold=0.02),
    )
}


def tool_sdf_url(name: str) -> str:
    """Package URL of a tool model, e.g. package://seqdex_models/tools/hammer/hammer.sdf.

    Raises:
        ValueError: for an unknown tool name; the message lists the valid names.
    """
    if name not in TOOL_SPECS:
        raise ValueError(f"unknown tool {name!r}; valid tools are {sorted(TOOL_SPECS)}")
    return f"package://{PACKAGE_NAME}/tools/{name}/{name}.sdf"


def _hull(*point_sets) -> manifold3d.Manifold:
    """Convex hull of the union of several point sets."""
    return decomposition.hull_manifold(np.vstack(point_sets))


def _ring_z(radius: float, z: float, center_xy=(0.0, 0.0)) -> np.ndarray:
    """A horizontal circle (polygon) of the given radius at height z."""
    return decomposition.circle_points(radius, z, _SEGMENTS, center_xy)


def _ellipse_y(semi_x: float, semi_z: float, y: float, z_center: float) -> np.ndarray:
    """An elliptical cross-section in the plane y = const (for handles running along y)."""
    ellipse = decomposition.ellipse_points(semi_x, semi_z, _SEGMENTS)
    return np.column_stack([ellipse[:, 0], np.full(len(ellipse), y), z_center + ellipse[:, 1]])


def _rect_y(half_x: float, z_low: float, z_high: float, y: float) -> np.ndarray:
    """A rectangle in the plane y = const."""
    return np.array([(sx * half_x, y, z) for sx in (-1.0, 1.0) for z in (z_low, z_high)])


def _hammer_solids() -> list[manifold3d.Manifold]:
    """Head (steel) and handle (hickory) of the hammer; bounding box 0.034 x 0.378 x 0.141 m."""
    head_y = 0.189 - 0.017  # The round face (radius 0.017) touches the +y end of the bounding box.
    center = (0.0, head_y)
    face = _hull(_ring_z(0.0155, -0.0705, center), _ring_z(0.017, -0.069, center), _ring_z(0.017, -0.063, center),
                 _ring_z(0.0115, -0.048, center))
    neck = _hull(_ring_z(0.0115, -0.0485, center), _ring_z(0.0115, -0.03, center))
    eye = decomposition.hull_manifold(decomposition.box_points((-0.0095, head_y - 0.0105, -0.031),
                                                               (0.0095, head_y + 0.0105, 0.008)))
    peen = decomposition.hull_manifold(np.vstack([
        decomposition.box_points((-0.0095, head_y - 0.0105, 0.0075), (0.0095, head_y + 0.0105, 0.0076)),
        decomposition.box_points((-0.0035, head_y - 0.0015, 0.0704), (0.0035, head_y + 0.0015, 0.0705)),
    ]))
    head = decomposition.union([face, neck, eye, peen])
    handle = _hull(_ellipse_y(0.0125, 0.0155, -0.189, -0.0115), _ellipse_y(0.0085, 0.011, head_y, -0.0115))
    return [head, handle - head]


def _spatula_solids() -> list[manifold3d.Manifold]:
    """Blade with neck (nylon) and handle (beech) of the spatula; bounding box 0.167 x 0.724 x 0.080 m."""
    outline = [(0.05, 0.20), (0.0835, 0.26), (0.0835, 0.347), (0.0685, 0.362)]
    outline = outline + [(-x, y) for x, y in reversed(outline)]
    blade = decomposition.hull_manifold(
        np.array([(x, y, z) for x, y in outline for z in (-0.040, -0.037)]))
    neck = _hull(_rect_y(0.012, -0.040, -0.036, 0.215), _rect_y(0.010, 0.018, 0.023, 0.045))
    blade_and_neck = decomposition.union([blade, neck])
    handle = _hull(_ellipse_y(0.014, 0.011, -0.362, 0.029), _ellipse_y(0.0115, 0.009, 0.065, 0.029))
    return [blade_and_neck - handle, handle]


def _spoon_solids() -> list[manifold3d.Manifold]:
    """The ladle (one nylon solid); bounding box 0.134 x 0.497 x 0.164 m."""
    radius, wall, rim_z = 0.067, 0.003, -0.015
    bowl_y = 0.2485 - radius
    outer = manifold3d.Manifold.sphere(radius, 96).translate((0.0, bowl_y, rim_z))
    inner = manifold3d.Manifold.sphere(radius - wall, 96).translate((0.0, bowl_y, rim_z))
    below_rim = decomposition.hull_manifold(decomposition.box_points((-0.1, bowl_y - 0.1, rim_z - 0.1),
                                                                     (0.1, bowl_y + 0.1, rim_z)))
    bowl = (outer - inner) ^ below_rim
    rim_y = bowl_y - radius
    lower = _hull(_rect_y(0.008, rim_z - 0.004, rim_z + 0.002, rim_y + 0.0035),
                  _rect_y(0.008, 0.057, 0.063, 0.03))
    grip = _hull(_rect_y(0.008, 0.057, 0.063, 0.03), _rect_y(0.014, 0.076, 0.082, -0.2485))
    return [decomposition.union([bowl, lower, grip])]


_BUILDERS = {"hammer": _hammer_solids, "spatula": _spatula_solids, "spoon": _spoon_solids}


def tool_solids(name: str) -> list[manifold3d.Manifold]:
    """Solids of a tool's materials (same order as `TOOL_SPECS[name].materials`), moved so that the origin is
    at the centre of the tool's bounding box.

    Raises:
        ValueError: for an unknown tool name.
    """
    tool_sdf_url(name)
    solids = _BUILDERS[name]()
    low, high = np.array(decomposition.union(solids).bounding_box()).reshape(2, 3)
    center = (low + high) / 2
    return [solid.translate(tuple(-center)) for solid in solids]


def generate_tool(name: str, out_dir: str) -> dict:
    """Writes a tool's visual OBJs, CoACD convex pieces and SDF under `<out_dir>/tools/<name>/`.

    Args:
        name: "hammer", "spatula" or "spoon".
        out_dir: the models root.

    Returns:
        A summary: mass (kg), centre of mass, number of convex pieces, bounding box.
    """
    tool_sdf_url(name)
    spec = TOOL_SPECS[name]
    tool_dir = os.path.join(out_dir, "tools", name)
    solids = tool_solids(name)
    # The union is meshed first: manifold3d evaluates lazily, so meshing the parts first would change how the
    # union is triangulated (still deterministic, but then CoACD's input would depend on this order).
    whole = decomposition.manifold_to_trimesh(decomposition.union(solids))
    meshes = [decomposition.manifold_to_trimesh(solid) for solid in solids]
    visuals, inertials = [], []
    for material, mesh in zip(spec.materials, meshes, strict=True):
        if not mesh.is_watertight:
            raise RuntimeError(f"{name}: {material.name} mesh is not watertight")
        file = f"visual_{material.name}.obj"
        decomposition.write_obj(os.path.join(tool_dir, file), mesh, comment=f"{name} {material.name}")
        visuals.append(sdf_writer.Visual(material.name, sdf_writer.mesh(file), material.rgba))
        inertials.append(sdf_writer.inertial_from_mesh(mesh, material.density))
    pieces = decomposition.coacd_pieces(whole, threshold=spec.coacd_threshold, seed=COACD_SEED)
    files = decomposition.write_pieces(os.path.join(tool_dir, "pieces"), pieces)
    collisions = [
        sdf_writer.Collision(f"collision_{k:03d}", sdf_writer.mesh(f"pieces/{file}", convex=True), TOOL_PROXIMITY)
        for k, file in enumerate(files)
    ]
    inertial = sdf_writer.combine_inertials(inertials)
    link = sdf_writer.Link("tool", inertial, visuals, collisions)
    comment = f"{name}: {spec.description}; origin at the bounding-box centre; {len(files)} convex pieces"
    sdf_writer.write_sdf(os.path.join(tool_dir, f"{name}.sdf"), name, [link], comment)
    bounds = np.vstack([m.bounds for m in meshes])
    return {"name": name, "mass": inertial.mass, "center_of_mass": inertial.center_of_mass.tolist(),
            "pieces": len(files), "extent": (bounds.max(axis=0) - bounds.min(axis=0)).tolist()}
