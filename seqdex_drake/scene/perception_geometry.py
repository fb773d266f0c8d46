"""Low-poly perception geometry: what the cameras render, at a lower level of detail than Meshcat shows.

The label camera of Search renders on the CPU (VTK on Mesa's software rasterizer), and there its cost is set
by triangles, not pixels: a 128 x 128 label image of the Search scene took ~45 ms, about the same at 16 x 16.
VTK tessellates every sphere and capsule finely (a visible sphere cost ~0.7 ms to draw, a capsule ~1 ms, a
box 0.07 ms), so the Allegro hand's 4 fingertip spheres and 13 capsules cost ~17 ms, and the 72 blocks' visual
meshes (750-1400 triangles each) ~23 ms.

:func:`UseLowPolyPerceptionGeometry` moves the perception role of such geometry to a low-poly stand-in on the
same frame, at the same pose, with the same perception properties (so the same render label): spheres,
capsules, cylinders and ellipsoids become meshes of ~50-100 triangles with their vertices on the true surface;
a mesh file with a ``perception.obj`` beside it (the blocks: their coarse convex pieces, written by
``scripts/generate_assets.py``) renders that file instead, at the same scale. The original geometry keeps its
illustration (Meshcat) and proximity (contact) roles. Boxes and meshes without a stand-in are left alone.
"""

import os

import trimesh
from pydrake.common import MemoryFile
from pydrake.geometry import (
    Capsule,
    Cylinder,
    Ellipsoid,
    GeometryInstance,
    InMemoryMesh,
    Mesh,
    PerceptionProperties,
    Role,
    SceneGraph,
    Sphere,
)
from pydrake.multibody.plant import MultibodyPlant

#: File name of a mesh's perception stand-in, looked up in the directory of the mesh file.
STAND_IN_FILE = "perception.obj"
#: Segments around the axis of the stand-ins of capsules and cylinders.
RADIAL_SEGMENTS = 10


def _obj_text(mesh: trimesh.Trimesh) -> str:
    """OBJ text with vertex normals (VTK requires normals)."""
    vertices = "".join(f"v {x:.6g} {y:.6g} {z:.6g}\n" for x, y, z in mesh.vertices)
    normals = "".join(f"vn {x:.6g} {y:.6g} {z:.6g}\n" for x, y, z in mesh.vertex_normals)
    faces = "".join(f"f {a + 1}//{a + 1} {b + 1}//{b + 1} {c + 1}//{c + 1}\n" for a, b, c in mesh.faces)
    return vertices + normals + faces


def _in_memory(mesh: trimesh.Trimesh, hint: str) -> Mesh:
    return Mesh(InMemoryMesh(mesh_file=MemoryFile(_obj_text(mesh), ".obj", hint)))


def low_poly_shape(shape):
    """The low-poly perception stand-in of ``shape``, or None where it has none (boxes, meshes without a
    ``perception.obj`` beside them, convex hulls, half-spaces)."""
    if isinstance(shape, Sphere):
        return _in_memory(trimesh.creation.icosphere(subdivisions=1, radius=shape.radius()), "sphere stand-in")
    if isinstance(shape, Ellipsoid):
        sphere = trimesh.creation.icosphere(subdivisions=1, radius=1.0)
        sphere.vertices *= [shape.a(), shape.b(), shape.c()]
        return _in_memory(sphere, "ellipsoid stand-in")
    if isinstance(shape, Capsule):  # Both are centred on their frame, along its z axis, in trimesh as in Drake.
        capsule = trimesh.creation.capsule(height=shape.length(), radius=shape.radius(),
                                           count=[RADIAL_SEGMENTS, RADIAL_SEGMENTS // 2])
        return _in_memory(capsule, "capsule stand-in")
    if isinstance(shape, Cylinder):
        cylinder = trimesh.creation.cylinder(radius=shape.radius(), height=shape.length(), sections=RADIAL_SEGMENTS)
        return _in_memory(cylinder, "cylinder stand-in")
    if isinstance(shape, Mesh) and shape.source().is_path():
        stand_in = os.path.join(os.path.dirname(str(shape.source().path())), STAND_IN_FILE)
        if os.path.exists(stand_in) and os.path.basename(str(shape.source().path())) != STAND_IN_FILE:
            return Mesh(stand_in, shape.scale3())
    return None


def UseLowPolyPerceptionGeometry(plant: MultibodyPlant, scene_graph: SceneGraph) -> int:
    """Moves the perception role of the plant's finely tessellated geometry to low-poly stand-ins (see the
    module docstring). Call after the plant is finalized, before the diagram is built. Returns how many
    geometries were replaced."""
    inspector = scene_graph.model_inspector()
    source_id = plant.get_source_id()
    replaced = 0
    for geometry_id in inspector.GetAllGeometryIds(Role.kPerception):
        if inspector.GetOwningSourceName(geometry_id) != inspector.GetName(source_id):
            continue  # Not the plant's: someone else's geometry is theirs to change.
        stand_in = low_poly_shape(inspector.GetShape(geometry_id))
        if stand_in is None:
            continue
        instance = GeometryInstance(inspector.GetPoseInFrame(geometry_id), stand_in,
                                    f"{inspector.GetName(geometry_id)}_perception")
        instance.set_perception_properties(PerceptionProperties(inspector.GetPerceptionProperties(geometry_id)))
        frame_id = inspector.GetFrameId(geometry_id)
        scene_graph.RemoveRole(source_id, geometry_id, Role.kPerception)
        if frame_id == inspector.world_frame_id():
            scene_graph.RegisterAnchoredGeometry(source_id, instance)
        else:
            scene_graph.RegisterGeometry(source_id, frame_id, instance)
        replaced += 1
    return replaced
