"""Convex pieces for collision geometry, and the mesh I/O they share with the visual meshes.

Two ways to obtain convex pieces live here:

* Parametric: a part that is convex by construction (a box, a prism over a convex polygon, a chamfered
  cylinder) is the convex hull of a few points; `hull_mesh` turns such a point set into a closed triangle mesh.
* Decomposed: `coacd_pieces` runs CoACD (approximate convex decomposition) on an arbitrary watertight mesh with
  an explicit seed, and returns the hulls in a canonical order so that reruns write identical files.

All meshes are written by `write_obj` with a fixed float format, so regenerating an asset on the same machine
reproduces every file byte for byte.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Sequence

import manifold3d
import numpy as np
import trimesh

# Coordinates are written (and rounded before any mass computation) to this many decimals: 1 micrometre.
OBJ_DECIMALS = 6


def round_vertices(vertices: np.ndarray) -> np.ndarray:
    """Rounds vertices to the written precision, mapping -0.0 to 0.0 so the text form is canonical."""
    return np.round(np.asarray(vertices, dtype=float), OBJ_DECIMALS) + 0.0


def manifold_to_trimesh(solid: manifold3d.Manifold) -> trimesh.Trimesh:
    """Converts a manifold3d solid to a trimesh mesh (vertices rounded to the written precision).

    Args:
        solid: a non-empty manifold3d solid.

    Returns:
        A `trimesh.Trimesh` with the same triangles; `process=False` keeps manifold's vertex order.
    """
    mesh = solid.to_mesh()
    vertices = round_vertices(np.asarray(mesh.vert_properties)[:, :3])
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)


def hull_manifold(points: np.ndarray) -> manifold3d.Manifold:
    """Returns the convex hull of a point cloud as a manifold3d solid."""
    return manifold3d.Manifold.hull_points(np.ascontiguousarray(points, dtype=float))


def hull_mesh(points: np.ndarray) -> trimesh.Trimesh:
    """Returns the convex hull of a point cloud as a closed triangle mesh (one convex collision piece)."""
    return manifold_to_trimesh(hull_manifold(points))


def union(solids: Sequence[manifold3d.Manifold]) -> manifold3d.Manifold:
    """Exact boolean union of solids (manifold3d batch union)."""
    return manifold3d.Manifold.batch_boolean(list(solids), manifold3d.OpType.Add)


def circle_points(radius: float, z: float, segments: int, center=(0.0, 0.0)) -> np.ndarray:
    """Points of a regular polygon inscribed in a circle of the given radius in the plane at height z.

    The first vertex lies on the +x axis, so polygons of different resolutions share their extreme points.
    """
    angles = 2.0 * np.pi * np.arange(segments) / segments
    return np.column_stack(
        [center[0] + radius * np.cos(angles), center[1] + radius * np.sin(angles), np.full(segments, z)]
    )


def ellipse_points(semi_a: float, semi_b: float, segments: int) -> np.ndarray:
    """Vertices (u, v) of a polygon inscribed in an ellipse with semi-axes semi_a (along u) and semi_b."""
    angles = 2.0 * np.pi * np.arange(segments) / segments
    return np.column_stack([semi_a * np.cos(angles), semi_b * np.sin(angles)])


def chamfered_cylinder_points(
    radius: float, z_bottom: float, z_top: float, chamfer: float, segments: int, center=(0.0, 0.0)
) -> np.ndarray:
    """Point set whose hull is a vertical cylinder with a 45-degree chamfer on its top edge.

    Args:
        radius: cylinder radius (m); the polygon is inscribed in this circle.
        z_bottom: height of the flat bottom face.
        z_top: height of the flat top face.
        chamfer: size of the top-edge chamfer (m); 0 gives a plain cylinder.
        segments: polygon resolution.
        center: (x, y) of the axis.
    """
    rings = [circle_points(radius, z_bottom, segments, center)]
    if chamfer > 0.0:
        rings.append(circle_points(radius, z_top - chamfer, segments, center))
        rings.append(circle_points(radius - chamfer, z_top, segments, center))
    else:
        rings.append(circle_points(radius, z_top, segments, center))
    return np.vstack(rings)


def box_points(lower: Sequence[float], upper: Sequence[float]) -> np.ndarray:
    """The 8 corners of the axis-aligned box [lower, upper]."""
    lo, hi = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def prism_xz_points(polygon_xz: np.ndarray, y_min: float, y_max: float) -> np.ndarray:
    """Points of a prism: a polygon in the x-z plane extruded along y from y_min to y_max."""
    polygon_xz = np.asarray(polygon_xz, dtype=float)
    count = len(polygon_xz)
    near = np.column_stack([polygon_xz[:, 0], np.full(count, y_min), polygon_xz[:, 1]])
    far = np.column_stack([polygon_xz[:, 0], np.full(count, y_max), polygon_xz[:, 1]])
    return np.vstack([near, far])


def canonical_order(pieces: Iterable[trimesh.Trimesh]) -> list[trimesh.Trimesh]:
    """Sorts pieces by their rounded vertex centroid (x, then y, then z) so file numbering is stable."""
    pieces = list(pieces)
    keys = [tuple(np.round(piece.vertices.mean(axis=0), 5)) + (len(piece.vertices),) for piece in pieces]
    return [pieces[i] for i in sorted(range(len(pieces)), key=lambda i: keys[i])]


def coacd_pieces(
    mesh: trimesh.Trimesh,
    threshold: float,
    seed: int = 0,
    max_convex_hull: int = -1,
    preprocess_mode: str = "off",
    preprocess_resolution: int = 50,
    resolution: int = 2000,
) -> list[trimesh.Trimesh]:
    """Approximate convex decomposition of a watertight mesh with CoACD, deterministic for a given seed.

    Args:
        mesh: the watertight input mesh.
        threshold: CoACD concavity threshold (smaller gives more, tighter pieces).
        seed: CoACD's random seed; fixed so that reruns give identical pieces.
        max_convex_hull: upper bound on the number of pieces (-1: unbounded).
        preprocess_mode: CoACD manifold pre-processing ("off", "on", "auto"); our meshes are already
            watertight manifolds, and its voxel remeshing inflates thin parts (a 3 mm blade by ~4 mm), so off.
        preprocess_resolution: voxel resolution of that pre-processing when it runs.
        resolution: CoACD's sampling resolution for the concavity metric.

    Returns:
        The convex pieces in canonical order, each the convex hull of a CoACD part, vertices rounded.
    """
    import coacd  # Imported lazily: only the tool generator needs it.

    coacd.set_log_level("error")
    parts = coacd.run_coacd(
        coacd.Mesh(np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)),
        threshold=threshold,
        max_convex_hull=max_convex_hull,
        preprocess_mode=preprocess_mode,
        preprocess_resolution=preprocess_resolution,
        resolution=resolution,
        seed=seed,
    )
    return canonical_order(hull_mesh(np.asarray(vertices)) for vertices, _ in parts)


def _format_float(value: float) -> str:
    """Fixed-decimal text of a coordinate, with -0 written as 0."""
    text = f"{value:.{OBJ_DECIMALS}f}"
    return "0." + "0" * OBJ_DECIMALS if text == "-0." + "0" * OBJ_DECIMALS else text


def write_obj(path: str, mesh: trimesh.Trimesh, comment: str = "") -> None:
    """Writes a triangle mesh as a Wavefront OBJ with a fixed float format (byte-identical on rerun).

    Args:
        path: destination file; parent directories are created.
        mesh: the mesh; vertices are written rounded to `OBJ_DECIMALS` decimals.
        comment: optional one-line comment written at the top of the file.
    """
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    lines = ["# Generated by scripts/generate_assets.py (seqdex-drake); do not edit."]
    if comment:
        lines.append(f"# {comment}")
    for vertex in round_vertices(mesh.vertices):
        lines.append("v " + " ".join(_format_float(c) for c in vertex))
    # One normal per face (flat shading): Drake's VTK renderer refuses OBJ files without normals.
    for normal in np.round(np.asarray(mesh.face_normals, dtype=float), 6):
        lines.append("vn " + " ".join(_format_float(c) for c in normal))
    for k, face in enumerate(np.asarray(mesh.faces, dtype=np.int64) + 1, start=1):
        lines.append(f"f {face[0]}//{k} {face[1]}//{k} {face[2]}//{k}")
    with open(path, "w", encoding="ascii", newline="\n") as stream:
        stream.write("\n".join(lines) + "\n")


def write_pieces(directory: str, pieces: Sequence[trimesh.Trimesh], prefix: str = "piece") -> list[str]:
    """Writes convex pieces as `<prefix>_NNN.obj` in `directory`, removing stale pieces from an earlier run.

    Returns:
        The file names written, in order, relative to `directory`.
    """
    os.makedirs(directory, exist_ok=True)
    pattern = re.compile(rf"^{re.escape(prefix)}_\d{{3}}\.obj$")
    for name in sorted(os.listdir(directory)):
        if pattern.match(name):
            os.remove(os.path.join(directory, name))
    names = []
    for index, piece in enumerate(pieces):
        name = f"{prefix}_{index:03d}.obj"
        write_obj(os.path.join(directory, name), piece, comment=f"convex piece {index} of {len(pieces)}")
        names.append(name)
    return names
