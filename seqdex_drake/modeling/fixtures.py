"""Fixtures of the building-blocks scene: table, storage box, 12x12 baseplate and 4x4 plates (all welded).

Frames (z up in every model):

* table: origin at the centre of the top surface (top at z = 0, a 0.05 m slab below, legs down to z = -0.6);
  link "table". The scene welds it at z = 0.6.
* box: origin at the centre of the inner floor surface (floor 0.01 m thick below z = 0, walls up to z = 0.165);
  link "box". Inner footprint 0.60 x 0.416 m, walls 0.01 m thick.
* baseplate: origin at the bottom centre of the 0.36 m square, 0.018 m slab; 12x12 studs on top; link
  "baseplate".
* plate_N (N = 1, 2, 3): origin at the bottom centre of a solid 0.12 m square that is N block layers
  (0.0375 m each) tall, 4x4 studs on top; link "plate".

Studs are the blocks' slimmed studs (same convex piece), on the 0.03 m grid centred on the plate, so a block
whose stud grid is aligned with a plate's seats on it. Plate and baseplate visuals are exact unions (OBJ).
"""

from __future__ import annotations

import os

import numpy as np

from seqdex_drake.modeling import blocks, decomposition, sdf_writer

TABLE_SIZE = (1.5, 1.0, 0.05)
TABLE_HEIGHT = 0.6
TABLE_LEG = 0.05
BOX_INNER = (0.60, 0.416)
BOX_WALL_HEIGHT = 0.165
BOX_WALL_THICKNESS = 0.01
BOX_FLOOR_THICKNESS = 0.01
BASEPLATE_STUDS = 12
BASEPLATE_THICKNESS = 0.018
PLATE_STUDS = 4
PLATE_LAYERS = (1, 2, 3)
FIXTURE_NAMES = ("table", "box", "baseplate") + tuple(f"plate_{n}" for n in PLATE_LAYERS)

WOOD_DENSITY = 700.0
PLASTIC_DENSITY = 950.0
TABLE_RGBA = (0.60, 0.42, 0.24, 1.0)
BOX_RGBA = (0.55, 0.55, 0.58, 0.35)
BASEPLATE_RGBA = (0.10, 0.45, 0.15, 1.0)
PLATE_RGBA = (0.15, 0.35, 0.80, 1.0)
WOOD_PROXIMITY = sdf_writer.ProximityProperties(mu_dynamic=0.5, mu_static=0.6, hydroelastic_modulus=1.0e7)
STUD_MESH = "meshes/stud.obj"
FIXTURE_VISUAL_STUD_SEGMENTS = 24  # Coarser than the blocks: the baseplate has 144 studs.


def stud_mesh():
    """The fine convex stud piece in its own frame (base centre at the origin, axis +z)."""
    return decomposition.hull_mesh(decomposition.chamfered_cylinder_points(
        blocks.STUD_RADIUS, 0.0, blocks.STUD_HEIGHT, blocks.STUD_CHAMFER, blocks.FINE.stud_segments))


def stud_grid(count: int) -> np.ndarray:
    """(count^2, 2) stud centres of a count x count plate, on the 0.03 m grid centred at the origin."""
    offsets = (np.arange(count) - (count - 1) / 2) * blocks.STUD_PITCH
    return np.array([(x, y) for x in offsets for y in offsets])


def _plate_visual(count: int, thickness: float):
    """Exact union of the slab and its studs at visual resolution."""
    side = count * blocks.STUD_PITCH
    parts = [decomposition.hull_manifold(decomposition.box_points((-side / 2, -side / 2, 0.0),
                                                                  (side / 2, side / 2, thickness)))]
    for center in stud_grid(count):
        parts.append(decomposition.hull_manifold(decomposition.chamfered_cylinder_points(
            blocks.STUD_RADIUS, thickness, thickness + blocks.STUD_HEIGHT, blocks.STUD_CHAMFER,
            FIXTURE_VISUAL_STUD_SEGMENTS, center)))
    return decomposition.manifold_to_trimesh(decomposition.union(parts))


def _write_plate(out_dir: str, model_name: str, link_name: str, count: int, thickness: float, rgba) -> dict:
    """Writes a studded plate: visual union mesh, shared stud piece, SDF with a slab box and stud pieces."""
    fixture_dir = os.path.join(out_dir, "fixtures")
    visual_file = f"meshes/{model_name}_visual.obj"
    mesh = _plate_visual(count, thickness)
    if not mesh.is_watertight:
        raise RuntimeError(f"{model_name}: visual mesh is not watertight")
    decomposition.write_obj(os.path.join(fixture_dir, visual_file), mesh, comment=f"{model_name} visual")
    decomposition.write_obj(os.path.join(fixture_dir, STUD_MESH), stud_mesh(), comment="slimmed stud")
    side = count * blocks.STUD_PITCH
    properties = blocks.BLOCK_PROXIMITY
    collisions = [sdf_writer.Collision("slab", sdf_writer.box((side, side, thickness)), properties,
                                       (0.0, 0.0, thickness / 2, 0.0, 0.0, 0.0))]
    for k, (x, y) in enumerate(stud_grid(count)):
        collisions.append(sdf_writer.Collision(f"stud_{k:03d}", sdf_writer.mesh(STUD_MESH, convex=True),
                                               properties, (x, y, thickness, 0.0, 0.0, 0.0)))
    inertial = sdf_writer.inertial_from_mesh(mesh, PLASTIC_DENSITY)
    visual = sdf_writer.Visual("visual", sdf_writer.mesh(visual_file), rgba)
    link = sdf_writer.Link(link_name, inertial, (visual,), collisions)
    comment = f"{count}x{count}-stud plate, {thickness} m thick, origin at the bottom centre"
    sdf_writer.write_sdf(os.path.join(fixture_dir, f"{model_name}.sdf"), model_name, [link], comment)
    return {"name": model_name, "mass": inertial.mass, "collisions": len(collisions)}


def _write_table(out_dir: str) -> dict:
    """Writes table.sdf: a box top (collision and visual) and four visual legs."""
    length, width, thickness = TABLE_SIZE
    leg_length = TABLE_HEIGHT - thickness
    top_center = (0.0, 0.0, -thickness / 2)
    parts = [sdf_writer.box_inertial(TABLE_SIZE, WOOD_DENSITY, top_center)]
    visuals = [sdf_writer.Visual("top", sdf_writer.box(TABLE_SIZE), TABLE_RGBA, top_center + (0.0, 0.0, 0.0))]
    inset_x, inset_y = length / 2 - TABLE_LEG, width / 2 - TABLE_LEG
    leg_size = (TABLE_LEG, TABLE_LEG, leg_length)
    for k, (sx, sy) in enumerate(((-1, -1), (-1, 1), (1, -1), (1, 1))):
        center = (sx * inset_x, sy * inset_y, -thickness - leg_length / 2)
        parts.append(sdf_writer.box_inertial(leg_size, WOOD_DENSITY, center))
        visuals.append(sdf_writer.Visual(f"leg_{k}", sdf_writer.box(leg_size), TABLE_RGBA,
                                         center + (0.0, 0.0, 0.0)))
    collisions = [sdf_writer.Collision("top", sdf_writer.box(TABLE_SIZE), WOOD_PROXIMITY,
                                       top_center + (0.0, 0.0, 0.0))]
    inertial = sdf_writer.combine_inertials(parts)
    link = sdf_writer.Link("table", inertial, visuals, collisions)
    comment = "1.5 x 1.0 m table; top surface at z = 0 (weld the model frame at the table height)"
    sdf_writer.write_sdf(os.path.join(out_dir, "fixtures", "table.sdf"), "table", [link], comment)
    return {"name": "table", "mass": inertial.mass, "collisions": len(collisions)}


def _box_panels() -> list[tuple[str, tuple[float, float, float], tuple[float, float, float]]]:
    """(name, size, centre) of the floor and four walls of the storage box."""
    inner_x, inner_y = BOX_INNER
    t, floor, height = BOX_WALL_THICKNESS, BOX_FLOOR_THICKNESS, BOX_WALL_HEIGHT
    outer_x, outer_y = inner_x + 2 * t, inner_y + 2 * t
    wall_z = (height - floor) / 2
    return [
        ("floor", (outer_x, outer_y, floor), (0.0, 0.0, -floor / 2)),
        ("wall_neg_x", (t, outer_y, height + floor), (-(inner_x + t) / 2, 0.0, wall_z)),
        ("wall_pos_x", (t, outer_y, height + floor), ((inner_x + t) / 2, 0.0, wall_z)),
        ("wall_neg_y", (inner_x, t, height + floor), (0.0, -(inner_y + t) / 2, wall_z)),
        ("wall_pos_y", (inner_x, t, height + floor), (0.0, (inner_y + t) / 2, wall_z)),
    ]


def _write_box(out_dir: str) -> dict:
    """Writes box.sdf: translucent floor and walls; the four walls collide (the table top is the floor)."""
    panels = _box_panels()
    visuals, collisions, parts = [], [], []
    for name, size, center in panels:
        pose = center + (0.0, 0.0, 0.0)
        visuals.append(sdf_writer.Visual(name, sdf_writer.box(size), BOX_RGBA, pose))
        # The box stands on the table, whose top is the box's inner floor: a floor collision there would be
        # coplanar with the table top and double every resting contact, so only the walls collide.
        if name != "floor":
            collisions.append(sdf_writer.Collision(name, sdf_writer.box(size), WOOD_PROXIMITY, pose))
    # The floor spans the full outer footprint; the walls stand on top of its edges, so no volume overlaps.
    for name, size, center in panels:
        height = size[2] - (BOX_FLOOR_THICKNESS if name != "floor" else 0.0)
        z = center[2] + (BOX_FLOOR_THICKNESS / 2 if name != "floor" else 0.0)
        parts.append(sdf_writer.box_inertial((size[0], size[1], height), PLASTIC_DENSITY, (center[0], center[1], z)))
    inertial = sdf_writer.combine_inertials(parts)
    link = sdf_writer.Link("box", inertial, visuals, collisions)
    comment = "open storage box; origin at the inner floor centre (inner floor surface at z = 0)"
    sdf_writer.write_sdf(os.path.join(out_dir, "fixtures", "box.sdf"), "box", [link], comment)
    return {"name": "box", "mass": inertial.mass, "collisions": len(collisions)}


def generate_fixture(name: str, out_dir: str) -> dict:
    """Writes one fixture's SDF (and meshes) under `<out_dir>/fixtures/`.

    Args:
        name: one of `FIXTURE_NAMES`.
        out_dir: the models root.

    Returns:
        A summary with the model name, mass and number of collision geometries.

    Raises:
        ValueError: for an unknown fixture name; the message lists the valid names.
    """
    if name == "table":
        return _write_table(out_dir)
    if name == "box":
        return _write_box(out_dir)
    if name == "baseplate":
        return _write_plate(out_dir, "baseplate", "baseplate", BASEPLATE_STUDS, BASEPLATE_THICKNESS, BASEPLATE_RGBA)
    for layers in PLATE_LAYERS:
        if name == f"plate_{layers}":
            return _write_plate(out_dir, name, "plate", PLATE_STUDS, layers * blocks.BODY_HEIGHT, PLATE_RGBA)
    raise ValueError(f"unknown fixture {name!r}; valid fixtures are {list(FIXTURE_NAMES)}")


def fixture_sdf_url(name: str) -> str:
    """Package URL of a fixture model, e.g. package://seqdex_models/fixtures/table.sdf.

    Raises:
        ValueError: for an unknown fixture name; the message lists the valid names.
    """
    if name not in FIXTURE_NAMES:
        raise ValueError(f"unknown fixture {name!r}; valid fixtures are {list(FIXTURE_NAMES)}")
    return f"package://{blocks.PACKAGE_NAME}/fixtures/{name}.sdf"
