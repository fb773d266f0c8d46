"""Mega Bloks geometry: eight block types built from convex parts, with their SDF models and pile directives.

Body frame of every block: origin at the centre of the bottom rim (z = 0 is the bottom of the walls), x along
the long side, y along the short side, studs pointing +z. The body is `BODY_HEIGHT` tall and studs rise
`STUD_HEIGHT` above it, so every block is 0.0575 m tall in total. Stud centres lie on the 0.03 m grid centred on
the footprint.

A block is hollow underneath: 3 mm outer walls, a 10 mm top plate and a 27.5 mm deep cavity (plate studs are
20 mm tall). Inside the cavity, locating features sized for the nominal 18 mm stud centre the block on a stud
grid: a rib on the wall facing every stud position along each wall, and on the 2x2 block also a central post
touching all four studs below it. The studs themselves are slimmed to 16.5 mm (as the paper did), which
leaves 0.75 mm of play per side, so an aligned block dropped onto a plate seats by free fall. Ribs and posts
have a 1.5 mm lead-in chamfer at the bottom. Curved blocks replace the top over their stud-less cells by a
superellipse quadrant that falls to a lower lip at the +x end; the cavity ceiling follows 3 mm below it where
needed, staying above the studs of a block underneath.

Every part is convex (boxes, prisms under a concave top profile, chamfered cylinders, hulls), so the collision
geometry is exactly the list of parts: the fine set keeps the locating features and resolves curves and studs
finely, the coarse set drops the locating features (the cavity stays open) and uses coarse polygons. The visual
mesh is the exact boolean union of the parts at a higher resolution; its solid volume times `DENSITY` is the
mass.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import trimesh

from seqdex_drake.modeling import decomposition, sdf_writer

PACKAGE_NAME = "seqdex_models"
STUD_PITCH = 0.03
BODY_HEIGHT = 0.0375
STUD_HEIGHT = 0.02
TOTAL_HEIGHT = BODY_HEIGHT + STUD_HEIGHT
STUD_RADIUS = 0.00825  # Slimmed from the nominal 0.009 so that blocks seat by free fall.
STUD_RADIUS_NOMINAL = 0.009  # The locating ribs and posts are sized for this radius.
STUD_CHAMFER = 0.001
WALL_THICKNESS = 0.003
CAVITY_DEPTH = 0.0275
LOCATOR_WIDTH = 0.004  # Rib width along its wall.
LEAD_IN = 0.0015  # Horizontal size of the bottom chamfer of ribs and posts.
LEAD_IN_HEIGHT = 0.003
EMBED = 0.0005  # Ribs and posts reach this far into the wall or top plate they hang from (robust union).
DENSITY = 567.0  # kg/m^3, as in the authors' release.
RESOLUTIONS = ("coarse", "fine")
BLOCK_PROXIMITY = sdf_writer.ProximityProperties(mu_dynamic=0.7, mu_static=0.8, hydroelastic_modulus=1.0e7)


@dataclass(frozen=True)
class Resolution:
    """Polygon resolution of the parts and whether the cavity's locating features are included."""

    name: str
    stud_segments: int
    curve_segments: int
    post_segments: int
    locating_features: bool


VISUAL = Resolution("visual", stud_segments=48, curve_segments=24, post_segments=48, locating_features=True)
FINE = Resolution("fine", stud_segments=16, curve_segments=8, post_segments=16, locating_features=True)
COARSE = Resolution("coarse", stud_segments=8, curve_segments=3, post_segments=8, locating_features=False)
COLLISION_RESOLUTIONS = {"coarse": COARSE, "fine": FINE}


@dataclass(frozen=True)
class SlopeSpec:
    """A curved top over the stud-less cells: z = lip + (H - lip) (1 - u^e)^(1/e), u from 0 at start to 1 at +x.

    Attributes:
        start: where the curve begins, measured from the -x end of the block (m).
        lip_height: height of the top surface at the +x end (m).
        exponent: superellipse exponent e (2 is an ellipse quadrant; larger is fuller, i.e. softer).
    """

    start: float
    lip_height: float
    exponent: float


@dataclass(frozen=True)
class BlockSpec:
    """One Mega Bloks type.

    Attributes:
        block_type: type number, 1-8.
        name: descriptive name from the paper's block set.
        cells: (nx, ny) stud cells of the footprint; the footprint is (nx, ny) * STUD_PITCH.
        stud_cells: (i, j) cells carrying a stud, i along x from the -x end, j along y from the -y side.
        split: "trained" or "unseen" (held out from training in the paper).
        rgba: visual colour.
        slope: the curved top over the stud-less cells, or None for a flat-topped brick.
    """

    block_type: int
    name: str
    cells: tuple[int, int]
    stud_cells: tuple[tuple[int, int], ...]
    split: str
    rgba: tuple[float, float, float, float]
    slope: SlopeSpec | None = None

    @property
    def model_name(self) -> str:
        """Model (and directory) name, e.g. "block_3"."""
        return f"block_{self.block_type}"

    @property
    def footprint(self) -> tuple[float, float]:
        """(length along x, width along y) in metres."""
        return (self.cells[0] * STUD_PITCH, self.cells[1] * STUD_PITCH)

    @property
    def num_studs(self) -> int:
        """Number of studs on top."""
        return len(self.stud_cells)

    def cell_center(self, i: int, j: int) -> np.ndarray:
        """(x, y) of the centre of cell (i, j) in the body frame."""
        return np.array([(i - (self.cells[0] - 1) / 2) * STUD_PITCH, (j - (self.cells[1] - 1) / 2) * STUD_PITCH])

    @property
    def stud_centers(self) -> np.ndarray:
        """(num_studs, 2) stud centres (x, y) in the body frame."""
        return np.array([self.cell_center(i, j) for i, j in self.stud_cells])

    @property
    def socket_centers(self) -> np.ndarray:
        """(nx * ny, 2) centres of the cells underneath, where the studs of a block below go."""
        return np.array([self.cell_center(i, j) for i in range(self.cells[0]) for j in range(self.cells[1])])


BLOCK_SPECS: dict[int, BlockSpec] = {
    spec.block_type: spec
    for spec in (
        BlockSpec(1, "1x2", (2, 1), ((0, 0), (1, 0)), "trained", (0.80, 0.10, 0.10, 1.0)),
        BlockSpec(2, "1x2 curved slope", (2, 1), ((0, 0),), "trained", (0.95, 0.50, 0.05, 1.0),
                  SlopeSpec(start=0.03, lip_height=0.015, exponent=1.5)),
        BlockSpec(3, "1x3 soft curve", (2, 1), ((0, 0),), "trained", (0.95, 0.80, 0.10, 1.0),
                  SlopeSpec(start=0.025, lip_height=0.0225, exponent=2.5)),
        BlockSpec(4, "1x3", (3, 1), ((0, 0), (1, 0), (2, 0)), "trained", (0.55, 0.20, 0.70, 1.0)),
        BlockSpec(5, "1x4", (4, 1), ((0, 0), (1, 0), (2, 0), (3, 0)), "trained", (0.10, 0.70, 0.80, 1.0)),
        BlockSpec(6, "1x3 curved", (3, 1), ((0, 0),), "unseen", (0.95, 0.45, 0.65, 1.0),
                  SlopeSpec(start=0.03, lip_height=0.019, exponent=2.0)),
        BlockSpec(7, "1x1", (1, 1), ((0, 0),), "unseen", (0.92, 0.92, 0.92, 1.0)),
        BlockSpec(8, "2x2 soft curve", (2, 2), ((0, 0), (0, 1)), "unseen", (0.55, 0.85, 0.15, 1.0),
                  SlopeSpec(start=0.03, lip_height=0.0225, exponent=2.5)),
    )
}


def _check_block_type(block_type: int) -> BlockSpec:
    """The spec of a block type; ValueError listing the valid types otherwise."""
    if block_type not in BLOCK_SPECS:
        raise ValueError(f"unknown block type {block_type!r}; valid types are {sorted(BLOCK_SPECS)}")
    return BLOCK_SPECS[block_type]


def block_sdf_url(block_type: int, resolution: str) -> str:
    """Package URL of a block model, e.g. package://seqdex_models/blocks/block_1/block_1_coarse.sdf.

    Args:
        block_type: 1-8.
        resolution: "coarse" (Search, Orient, Grasp) or "fine" (Insert).

    Raises:
        ValueError: for an unknown type or resolution; the message lists the valid values.
    """
    spec = _check_block_type(block_type)
    if resolution not in RESOLUTIONS:
        raise ValueError(f"unknown resolution {resolution!r}; valid resolutions are {list(RESOLUTIONS)}")
    return f"package://{PACKAGE_NAME}/blocks/{spec.model_name}/{spec.model_name}_{resolution}.sdf"


def top_profile(spec: BlockSpec, curve_segments: int) -> tuple[np.ndarray, np.ndarray]:
    """The top surface as a concave polyline z(x) from -L/2 to +L/2 (breakpoints x, heights z)."""
    half = spec.footprint[0] / 2
    if spec.slope is None:
        return np.array([-half, half]), np.array([BODY_HEIGHT, BODY_HEIGHT])
    slope = spec.slope
    x0 = -half + slope.start
    u = np.linspace(0.0, 1.0, curve_segments + 1)
    shape = np.clip(1.0 - u**slope.exponent, 0.0, 1.0) ** (1.0 / slope.exponent)
    xs = np.concatenate([[-half], x0 + u * (half - x0)])
    zs = np.concatenate([[BODY_HEIGHT], slope.lip_height + (BODY_HEIGHT - slope.lip_height) * shape])
    return xs, zs


def _ceiling(x: np.ndarray, xs: np.ndarray, zs: np.ndarray) -> np.ndarray:
    """Cavity ceiling: the cavity depth, or 3 mm below the top surface where that is lower."""
    return np.minimum(CAVITY_DEPTH, np.interp(x, xs, zs) - WALL_THICKNESS)


def _breakpoints(spec: BlockSpec, xs: np.ndarray, zs: np.ndarray) -> np.ndarray:
    """Sorted x where the top or the ceiling changes slope, including the inner wall faces."""
    half = spec.footprint[0] / 2
    points = set(np.round(xs, 12)) | {round(-half + WALL_THICKNESS, 12), round(half - WALL_THICKNESS, 12)}
    offset = zs - WALL_THICKNESS - CAVITY_DEPTH  # The ceiling switches where top - t crosses the depth.
    for k in range(len(xs) - 1):
        if offset[k] * offset[k + 1] < 0.0:
            points.add(round(xs[k] + (xs[k + 1] - xs[k]) * offset[k] / (offset[k] - offset[k + 1]), 12))
    return np.array(sorted(points))


def _shell_parts(spec: BlockSpec, resolution: Resolution) -> list[np.ndarray]:
    """Point sets of the convex shell parts: two end walls, top-plate segments, two side walls."""
    half_x, half_y = spec.footprint[0] / 2, spec.footprint[1] / 2
    t = WALL_THICKNESS
    xs, zs = top_profile(spec, resolution.curve_segments)
    bx = _breakpoints(spec, xs, zs)
    top = np.interp(bx, xs, zs)
    inner = (bx >= -half_x + t - 1e-12) & (bx <= half_x - t + 1e-12)
    parts = []
    for end in (bx <= -half_x + t + 1e-12, bx >= half_x - t - 1e-12):  # End walls: hypograph of the top.
        polygon = [(bx[end][0], 0.0), (bx[end][-1], 0.0)] + list(zip(bx[end], top[end], strict=True))
        parts.append(decomposition.prism_xz_points(np.array(polygon), -half_y, half_y))
    x_in = bx[inner]
    ceiling = _ceiling(x_in, xs, zs)
    start = 0
    for k in range(1, len(x_in)):  # Top-plate segments, merged while top and ceiling stay linear.
        last = k == len(x_in) - 1
        if not last:
            slopes_before = np.diff(np.interp(x_in[k - 1:k + 1], xs, zs)), np.diff(ceiling[k - 1:k + 1])
            slopes_after = np.diff(np.interp(x_in[k:k + 2], xs, zs)), np.diff(ceiling[k:k + 2])
            widths = x_in[k] - x_in[k - 1], x_in[k + 1] - x_in[k]
            if all(abs(b / widths[0] - a / widths[1]) < 1e-9 for b, a in zip(slopes_before, slopes_after,
                                                                              strict=True)):
                continue
        segment = slice(start, k + 1)
        lower = list(zip(x_in[segment], ceiling[segment], strict=True))
        upper = list(zip(x_in[segment], np.interp(x_in[segment], xs, zs), strict=True))
        parts.append(decomposition.prism_xz_points(np.array(lower + upper), -half_y, half_y))
        start = k
    side_polygon = np.array([(x_in[0], 0.0), (x_in[-1], 0.0)] + list(zip(x_in, ceiling, strict=True)))
    parts.append(decomposition.prism_xz_points(side_polygon, -half_y, -half_y + t))
    parts.append(decomposition.prism_xz_points(side_polygon, half_y - t, half_y))
    return parts


def _stud_parts(spec: BlockSpec, resolution: Resolution) -> list[np.ndarray]:
    """Point sets of the chamfered studs on top of the body."""
    return [
        decomposition.chamfered_cylinder_points(
            STUD_RADIUS, BODY_HEIGHT, TOTAL_HEIGHT, STUD_CHAMFER, resolution.stud_segments, center
        )
        for center in spec.stud_centers
    ]


def _rib_points(along: tuple[float, float], wall: float, face: float, z_top: float, axis: int) -> np.ndarray:
    """A rib on a wall: spans `along` on the wall, reaches from `wall` to `face` across it, with a lead-in."""
    direction = np.sign(wall - face)
    lead_face, wall = face + direction * LEAD_IN, wall + direction * EMBED
    profile = [(wall, 0.0), (wall, z_top), (lead_face, 0.0), (face, LEAD_IN_HEIGHT), (face, z_top)]
    points = [(a, c, z) for a in along for c, z in profile]
    return np.array([(a, c, z) if axis == 0 else (c, a, z) for a, c, z in points])


def _locating_parts(spec: BlockSpec, resolution: Resolution) -> list[np.ndarray]:
    """Wall ribs facing every stud position next to a wall, and posts at interior grid vertices (2x2)."""
    half_x, half_y = spec.footprint[0] / 2, spec.footprint[1] / 2
    xs, zs = top_profile(spec, resolution.curve_segments)
    nx, ny = spec.cells
    parts = []
    for i in range(nx):  # Ribs on the two long walls (y = +-W/2), one facing each stud column.
        x = spec.cell_center(i, 0)[0]
        along = (x - LOCATOR_WIDTH / 2, x + LOCATOR_WIDTH / 2)
        z_top = float(np.min(_ceiling(np.array(along), xs, zs)))
        edge_stud = half_y - STUD_PITCH / 2
        for side in (-1.0, 1.0):
            wall, face = side * (half_y - WALL_THICKNESS), side * (edge_stud + STUD_RADIUS_NOMINAL)
            parts.append(_rib_points(along, wall, face, z_top, axis=0))
    edge_stud = half_x - STUD_PITCH / 2
    for j in range(ny):  # Ribs on the two end walls (x = +-L/2), one facing each stud row.
        y = spec.cell_center(0, j)[1]
        for side in (-1.0, 1.0):
            wall, face = side * (half_x - WALL_THICKNESS), side * (edge_stud + STUD_RADIUS_NOMINAL)
            z_top = float(np.min(_ceiling(np.array([wall, face]), xs, zs)))
            parts.append(_rib_points((y - LOCATOR_WIDTH / 2, y + LOCATOR_WIDTH / 2), wall, face, z_top, axis=1))
    radius = STUD_PITCH / np.sqrt(2.0) - STUD_RADIUS_NOMINAL  # A post touching its four nominal studs.
    for i in range(1, nx):
        for j in range(1, ny):
            center = (-half_x + i * STUD_PITCH, -half_y + j * STUD_PITCH)
            z_top = float(np.min(_ceiling(np.array([center[0] - radius, center[0] + radius]), xs, zs)))
            segments = resolution.post_segments
            parts.append(np.vstack([
                decomposition.circle_points(radius - LEAD_IN, 0.0, segments, center),
                decomposition.circle_points(radius, LEAD_IN_HEIGHT, segments, center),
                decomposition.circle_points(radius, z_top + EMBED, segments, center),
            ]))
    return parts


def block_parts(block_type: int, resolution: Resolution) -> list[np.ndarray]:
    """Point sets whose convex hulls are the parts of a block at the given resolution."""
    spec = _check_block_type(block_type)
    parts = _shell_parts(spec, resolution) + _stud_parts(spec, resolution)
    if resolution.locating_features:
        parts += _locating_parts(spec, resolution)
    return parts


def socket_clearance_volume(block_type: int, pieces, margin: float = 0.0005) -> float:
    """Volume (m^3) by which convex pieces overlap slimmed studs standing in every cell under the block.

    The studs are made `margin` taller than they are. Zero means the cavity is open: the block can sit on an
    aligned stud grid with its rim on the plate and at least `margin` of head room above every stud.
    """
    spec = _check_block_type(block_type)
    overlap = 0.0
    for center in spec.socket_centers:
        stud = decomposition.hull_manifold(decomposition.chamfered_cylinder_points(
            STUD_RADIUS, 0.0, STUD_HEIGHT + margin, STUD_CHAMFER, 32, center))
        for piece in pieces:
            overlap += (stud ^ decomposition.hull_manifold(np.asarray(piece.vertices))).volume()
    return overlap


def visual_mesh(block_type: int):
    """The watertight visual mesh: exact union of the parts at visual resolution (vertices rounded)."""
    solid = decomposition.union([decomposition.hull_manifold(p) for p in block_parts(block_type, VISUAL)])
    if len(solid.decompose()) != 1:
        raise RuntimeError(f"block {block_type}: parts do not form one connected solid")
    return decomposition.manifold_to_trimesh(solid)


def generate_block(block_type: int, out_dir: str) -> dict:
    """Writes visual.obj, coarse/ and fine/ convex pieces, perception.obj (the coarse pieces in one file: the
    cameras render it instead of visual.obj) and both SDF files of one block type.

    Args:
        block_type: 1-8.
        out_dir: the models root; files go to `<out_dir>/blocks/block_N/`.

    Returns:
        A summary: mass (kg), piece counts per resolution, the visual's bounds.
    """
    spec = _check_block_type(block_type)
    block_dir = os.path.join(out_dir, "blocks", spec.model_name)
    mesh = visual_mesh(block_type)
    if not mesh.is_watertight:
        raise RuntimeError(f"block {block_type}: visual mesh is not watertight")
    decomposition.write_obj(os.path.join(block_dir, "visual.obj"), mesh, comment=f"{spec.model_name} visual")
    inertial = sdf_writer.inertial_from_mesh(mesh, DENSITY)
    visual = sdf_writer.Visual("visual", sdf_writer.mesh("visual.obj"), spec.rgba)
    summary = {"name": spec.model_name, "mass": inertial.mass, "bounds": mesh.bounds.tolist()}
    for name, resolution in COLLISION_RESOLUTIONS.items():
        pieces = [decomposition.hull_mesh(points) for points in block_parts(block_type, resolution)]
        overlap = socket_clearance_volume(block_type, pieces)
        if overlap > 1e-12:
            raise RuntimeError(f"block {block_type} {name}: cavity overlaps the studs below by {overlap:.3g} m^3")
        files = decomposition.write_pieces(os.path.join(block_dir, name), pieces)
        if resolution is COARSE:  # The cameras' low-poly stand-in (scene/perception_geometry.py).
            decomposition.write_obj(os.path.join(block_dir, "perception.obj"), trimesh.util.concatenate(pieces),
                                    comment=f"{spec.model_name} perception stand-in: the coarse pieces")
        collisions = [
            sdf_writer.Collision(f"collision_{k:03d}", sdf_writer.mesh(f"{name}/{file}", convex=True),
                                 BLOCK_PROXIMITY)
            for k, file in enumerate(files)
        ]
        link = sdf_writer.Link("block", inertial, (visual,), collisions)
        comment = f"Mega Bloks type {block_type} ({spec.name}), {name} collision: {len(files)} convex pieces"
        sdf_writer.write_sdf(os.path.join(block_dir, f"{spec.model_name}_{name}.sdf"), spec.model_name, [link],
                             comment)
        summary[f"{name}_pieces"] = len(files)
    return summary


def pile_directives_text(resolution: str, copies: int = 9) -> str:
    """Drake model directives adding `copies` blocks of each type (names block_T_K), no poses."""
    lines = ["# Generated by scripts/generate_assets.py (seqdex-drake); do not edit.",
             f"# The 72-block pile ({resolution} collision); poses are set by the scene builder.",
             "directives:"]
    for block_type in sorted(BLOCK_SPECS):
        url = block_sdf_url(block_type, resolution)
        for copy in range(copies):
            lines.append(f"- add_model: {{name: block_{block_type}_{copy}, file: {url}}}")
    return "\n".join(lines) + "\n"


def write_pile_directives(out_dir: str) -> list[str]:
    """Writes building_blocks_pile_{coarse,fine}.dmd.yaml into the models root; returns the paths."""
    paths = []
    for resolution in RESOLUTIONS:
        path = os.path.join(out_dir, f"building_blocks_pile_{resolution}.dmd.yaml")
        os.makedirs(out_dir, exist_ok=True)
        with open(path, "w", encoding="ascii", newline="\n") as stream:
            stream.write(pile_directives_text(resolution))
        paths.append(path)
    return paths
