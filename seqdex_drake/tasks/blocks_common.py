"""Placing blocks for the Building Blocks sub-tasks: stable resting poses in the box, within reach, or on the
staging area (``STAGING_LOW`` .. ``STAGING_HIGH``), the clear table between the robot's base and the baseplate.

The paper's real-world protocol keeps task blocks 10 cm from the box edges; resets sample there too, and only
where the open hand hovering 5 cm above the block fits in the box: it hovers palm down with its fingers along +x,
their straight tips ``OPEN_HAND_REACH`` beyond the hand centre and the palm ``PALM_BACK_REACH`` behind it, and
blocks nearer the far or the near wall put the fingers or the palm inside the wall at the reset (21 of 150 resets
before the bounds; no action could free them).
"""

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw

from seqdex_drake.modeling.blocks import BLOCK_SPECS, TOTAL_HEIGHT
from seqdex_drake.observation_layout import rotation_matrix
from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q
from seqdex_drake.scene.piles import BOX_CENTER, BOX_INNER_HALF
from seqdex_drake.tasks.scripted.block_orient_script import roll_angle

BOX_MARGIN = 0.10
#: How far (m) the open hand's straight fingertips reach beyond the hand centre along +x, with a 1 cm clearance.
OPEN_HAND_REACH = 0.146 + 0.01
#: How far (m) behind the hand centre (-x) the hovering palm must clear the near wall: resets put it in the wall
#: for blocks at x < 0.08 m (the wall's inner face at -0.05 m), so 0.13 m plus a 1 cm clearance.
PALM_BACK_REACH = 0.13 + 0.01
#: The staging area: the (low, high) world xy corners of the clear table beside the box's near wall and the
#: baseplate's near edge (x 0.07 m), where a block taken out of the pile can be set down alone. The open hand
#: hovering over a block there clears the box's walls and the robot's base (its straight fingertips reach over the
#: flat baseplate's near edge); the shipped Orient and Grasp, trained in the box, stand up and lift blocks there
#: (``results/building_blocks.md``, "Out of the pile: the retrieve").
STAGING_LOW, STAGING_HIGH = np.array([-0.05, -0.40]), np.array([0.0, -0.20])
#: Reset regions of the single-block sub-tasks (``TaskConfig.reset_region``).
RESET_REGIONS = ("box", "staging")
#: Stable resting orientations (roll, pitch) of a brick: upright, upside down, on either long side.
RESTING = {"upright": (0.0, 0.0), "upside_down": (np.pi, 0.0), "side_left": (np.pi / 2, 0.0),
           "side_right": (-np.pi / 2, 0.0)}


def block_name(block_type: int) -> str:
    """Object name of the single block of ``block_type`` in the Orient/Grasp/Insert scenes."""
    if block_type not in BLOCK_SPECS:
        raise ValueError(f"unknown block type {block_type}; valid types: {sorted(BLOCK_SPECS)}")
    return f"block_{block_type}"


def resting_pose(block_type: int, roll: float, pitch: float, yaw: float, p_xy: np.ndarray,
                 floor: float = BOX_CENTER[2]) -> RigidTransform:
    """The pose of a block resting on ``floor`` at ``p_xy`` in the given orientation (bounding-box contact)."""
    length, width = BLOCK_SPECS[block_type].footprint
    rotation = RollPitchYaw(roll, pitch, yaw).ToRotationMatrix()
    corners = np.array([[x, y, z] for x in (-length / 2, length / 2) for y in (-width / 2, width / 2)
                        for z in (0.0, TOTAL_HEIGHT)])
    lowest = np.min((rotation.matrix() @ corners.T)[2])
    return RigidTransform(rotation, [p_xy[0], p_xy[1], floor - lowest + 0.0005])


def reachable_region() -> tuple[np.ndarray, np.ndarray]:
    """The (low, high) corners of where a block's centre may be for the hovering open hand to fit: at least
    ``BOX_MARGIN`` from the inner walls, ``OPEN_HAND_REACH`` from the far (+x) wall, ``PALM_BACK_REACH`` from the
    near one."""
    low = BOX_CENTER[:2] - (BOX_INNER_HALF - BOX_MARGIN)
    high = BOX_CENTER[:2] + (BOX_INNER_HALF - BOX_MARGIN)
    low[0] = max(low[0], BOX_CENTER[0] - BOX_INNER_HALF[0] + PALM_BACK_REACH)
    high[0] = min(high[0], BOX_CENTER[0] + BOX_INNER_HALF[0] - OPEN_HAND_REACH)
    return low, high


def sample_box_xy(rng: np.random.Generator) -> np.ndarray:
    """A position on the box floor in :func:`reachable_region`, where the hovering open hand must fit."""
    return rng.uniform(*reachable_region())


def sample_reset_xy(rng: np.random.Generator, region: str = "box") -> np.ndarray:
    """A block position in ``region`` (one of ``RESET_REGIONS``): :func:`sample_box_xy`, or uniform over the
    staging area. The box floor and the table top are at the same height (``BOX_CENTER[2]``)."""
    if region == "box":
        return sample_box_xy(rng)
    if region == "staging":
        return rng.uniform(STAGING_LOW, STAGING_HIGH)
    raise ValueError(f"unknown reset region {region!r}; valid regions: {', '.join(RESET_REGIONS)}")


#: A block whose centre has another block's centre within this horizontal distance (m) and more than
#: ``COVER_RISE`` (m) higher is covered (centres, not origins: :func:`centre_heights`).
COVER_RADIUS, COVER_RISE = 0.05, 0.01
#: A block whose centre lies less than this above the box floor rests on the floor, not on other blocks [m]. In
#: the pile Orient stood 1 of 49 such blocks against 9 of 49 resting on others (``experiments/pile_starts.py``), and
#: Grasp, the block stood upright in place, lifted none of 6 on the floor against 4 of 9 on others
#: (``experiments/grasp_in_pile.py``): the fingers need room below the block's neighbours.
ON_FLOOR = 0.035
#: A block tilted at most this far from upright [deg] stands up by Orient's side stroke alone (a quarter roll or
#: less); one tilted further must first be tipped from its back onto a side. In the pile Orient stood 9 of 47 of
#: the former against 1 of 51 of the latter (resting on others and uncovered: 7 of 17 against 1 of 25;
#: ``experiments/pile_starts.py``).
QUARTER_ROLL = 100.0


#: Orient's roll needs room on the side its top moves to: a neighbour whose centre lies within ``ROLL_ROOM`` (m)
#: of the block's centre along that direction, beside its length (within ``ROLL_BESIDE`` of its centre along the
#: long axis), and no more than ``ROLL_BELOW`` lower, stops the stroking fingertip or the roll (traced in the pile).
#: Over Orient's 98 starts in the pile that need a roll (``experiments/pile_starts.py``) it did not predict success.
ROLL_ROOM, ROLL_BESIDE, ROLL_BELOW = 0.10, 0.07, 0.01
#: The jaws of Grasp's pinch close along world x; a block whose long axis lies within 45 deg of x is pinched by
#: its ends and tilts in the lift (``results/building_blocks.md``), and Insert's goals lie along y.
ALONG_JAWS_COS = np.cos(np.radians(45.0))


def roll_blocked(q_blocks: np.ndarray, i: int) -> bool:
    """Whether every way Orient's roll would stand block ``i`` of ``q_blocks`` up is taken by a neighbour
    (``ROLL_ROOM``): a block on a long side stands up one way only (its top moving across its long axis, away from
    its open bottom), an upside-down one either way; an upright block needs no roll (False)."""
    R_WB = rotation_matrix(q_blocks[i, :4])
    roll = roll_angle(R_WB)
    across = np.cross(R_WB[:, 0], [0.0, 0.0, 1.0])
    norm = float(np.linalg.norm(across))
    if abs(roll) < np.radians(20.0) or norm < 1e-6:  # Upright, or its long axis vertical (no roll stands it up).
        return False
    across /= norm
    long_xy = np.array([-across[1], across[0], 0.0])
    ways = [across, -across] if abs(roll) > np.radians(170.0) else [-np.sign(roll) * across]
    d = np.delete(q_blocks[:, 4:], i, axis=0) - q_blocks[i, 4:]
    beside = (np.abs(d @ long_xy) < ROLL_BESIDE) & (d[:, 2] > -ROLL_BELOW)
    return all(bool(np.any(beside & (d @ e > 0.0) & (d @ e < ROLL_ROOM))) for e in ways)


def along_jaws(q_block: np.ndarray) -> bool:
    """Whether the block's long axis (body x), projected on the table, lies within 45 deg of world x."""
    x_W = rotation_matrix(q_block[:4])[:, 0]
    return bool(abs(x_W[0]) > ALONG_JAWS_COS * max(float(np.hypot(x_W[0], x_W[1])), 1e-9))


def centre_heights(q_blocks: np.ndarray) -> np.ndarray:
    """The world z of each block's centre (its origin is the middle of its bottom face: an upright block's origin
    lies 2.9 cm below its centre, a side-lying one's at its centre's height)."""
    return np.array([row[6] + rotation_matrix(row[:4])[2, 2] * TOTAL_HEIGHT / 2 for row in q_blocks])


def pick_keys(q_blocks: np.ndarray, i: int, heights: np.ndarray | None = None) -> dict:
    """What :func:`accessibility_order` sorts block row ``i`` of ``q_blocks`` by: its tilt [deg], whether another
    block's centre lies within ``COVER_RADIUS`` and ``COVER_RISE`` above its centre (covered), whether it rests on
    the box floor (``ON_FLOOR``), :func:`roll_blocked`, :func:`along_jaws` and its centre's height (``heights``:
    :func:`centre_heights` of ``q_blocks``, if known)."""
    heights = centre_heights(q_blocks) if heights is None else heights
    up_z = rotation_matrix(q_blocks[i, :4])[2, 2]  # The block's z axis, world z component.
    near = np.linalg.norm(q_blocks[:, 4:6] - q_blocks[i, 4:6], axis=1) < COVER_RADIUS
    return {"tilt": float(np.degrees(np.arccos(np.clip(up_z, -1.0, 1.0)))),
            "covered": bool(np.any(near & (heights > heights[i] + COVER_RISE))),
            "on_floor": bool(heights[i] - BOX_CENTER[2] < ON_FLOOR),
            "roll_blocked": roll_blocked(q_blocks, i), "along_jaws": along_jaws(q_blocks[i]),
            "height": float(heights[i])}


def accessibility_order(q_blocks: np.ndarray, candidates: list[int]) -> list[int]:
    """``candidates`` (rows of ``q_blocks``, an (N, 7) [wxyz, xyz] pile) ordered easiest to fetch first: centre
    in :func:`reachable_region` before outside it; resting on other blocks before on the box floor (``ON_FLOOR``);
    upright (tilt < 20 deg: Orient has nothing to do; in the pile Orient stood 7 of 7 such picks and about 1 in 10
    of the others) before any other; uncovered (no block centre within ``COVER_RADIUS`` and ``COVER_RISE`` above
    its centre) before covered; then at most a quarter roll from upright (``QUARTER_ROLL``) before tilted further;
    room for Orient's roll (:func:`roll_blocked`); the long axis across Grasp's jaws (:func:`along_jaws`); highest
    first (:func:`pick_keys`)."""
    low, high = reachable_region()
    heights = centre_heights(q_blocks)
    keys = []
    for i in candidates:
        p = q_blocks[i, 4:]
        inside = bool(np.all(p[:2] >= low) and np.all(p[:2] <= high))
        k = pick_keys(q_blocks, i, heights)
        keys.append((not inside, k["on_floor"], k["tilt"] >= 20.0, k["covered"], k["tilt"] > QUARTER_ROLL,
                     k["roll_blocked"], k["along_jaws"], -k["height"], i))
    return [key[-1] for key in sorted(keys)]


def retrieve_order(q_blocks: np.ndarray, candidates: list[int]) -> list[int]:
    """``candidates`` (rows of ``q_blocks``, an (N, 7) [wxyz, xyz] pile) ordered easiest to take out of the pile
    first, in whatever pose (``tasks/scripted/block_retrieve_script.py``): centre in :func:`reachable_region`
    before outside it; uncovered before covered; resting on other blocks before on the box floor (the pinch's
    jaws reach down past a high block's sides); highest first."""
    low, high = reachable_region()
    heights = centre_heights(q_blocks)
    keys = []
    for i in candidates:
        p = q_blocks[i, 4:]
        k = pick_keys(q_blocks, i, heights)
        keys.append((not bool(np.all(p[:2] >= low) and np.all(p[:2] <= high)), k["covered"], k["on_floor"],
                     -k["height"], i))
    return [key[-1] for key in sorted(keys)]


def place_single_block(env, rng: np.random.Generator, orientations: list[str]) -> str:
    """Parks every object, puts one block of a sampled type in the config's ``reset_region`` (the box or the
    staging area), hovers the open hand above it.

    Returns the target object's name (also declared to the environment).
    """
    block_type = int(rng.choice(env.config.object_types))
    name = block_name(block_type)
    env.objects.park(env.context)
    roll, pitch = RESTING[orientations[int(rng.integers(len(orientations)))]]
    X_WB = resting_pose(block_type, roll, pitch, rng.uniform(-np.pi, np.pi),
                         sample_reset_xy(rng, env.config.reset_region))
    env.objects.set_pose(env.context, name, X_WB, frozen=False)
    env.set_target(name)
    env.set_robot(env.hover_arm(env.object_position()), ALLEGRO_OPEN_Q)
    return name
