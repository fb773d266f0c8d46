"""Placing tools for the Tool Positioning sub-tasks (FACTS.md: tool at (0.29, 0.19) on the table, random yaw)."""

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw

from seqdex_drake.modeling.tools import TOOL_SPECS
from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q

TOOL_XY = np.array([0.29, 0.19])
TABLE_TOP = 0.6
SETTLE_TICKS = 30
TOOL_NAMES = tuple(TOOL_SPECS)
HELD_LIFT = 0.075
"""A tool counts as lifted and held while its origin is at least this far [m] above where it rests on the table
(the paper: "lifted and held in hand"; the chain's goal is 0.15 m up, ``evaluation/runner.TOOL_GOAL_LIFT``)."""
KNOCK_OUT_XY = 0.03
"""A knocked-out tool lands within this distance [m] of the tools' place on the table in x and y."""


def tool_name(index: int) -> str:
    """Object name of tool ``index`` (0 hammer: trained; 1 spatula, 2 spoon: unseen)."""
    if not 0 <= index < len(TOOL_NAMES):
        raise ValueError(f"unknown tool index {index}; valid: {dict(enumerate(TOOL_NAMES))}")
    return TOOL_NAMES[index]


def place_tool_on_table(env, rng: np.random.Generator) -> str:
    """Parks every object, lays a sampled tool on the table at a random yaw, lets it settle, hovers the hand."""
    name = tool_name(int(rng.choice(env.config.object_types)))
    env.objects.park(env.context)
    height = TOOL_SPECS[name].bounding_box[2]
    X_WT = RigidTransform(RollPitchYaw(0.0, 0.0, rng.uniform(-np.pi / 4, np.pi / 4)),
                          [*TOOL_XY, TABLE_TOP + height / 2 + 0.002])
    env.objects.set_pose(env.context, name, X_WT, frozen=False)
    env.set_target(name)
    env.set_robot(env.hover_arm(env.object_position() + [0.0, 0.0, height / 2]), ALLEGRO_OPEN_Q)
    for _ in range(SETTLE_TICKS):  # The tool comes to rest on its head and handle.
        env.simulator.AdvanceTo(env.context.get_time() + env.scenario.control_period)
    return name


def rest_height(name: str) -> float:
    """World height [m] of tool ``name``'s origin (its bounding-box centre) lying on the table."""
    return TABLE_TOP + TOOL_SPECS[name].bounding_box[2] / 2


def is_lifted(env) -> bool:
    """Whether the env's target tool is at least ``HELD_LIFT`` above its resting height."""
    return bool(env.object_pose().translation()[2] > rest_height(env.target_object) + HELD_LIFT)


def knock_out_tool(env, rng: np.random.Generator) -> None:
    """Knocks the env's target tool out of the hand: it lies on the table again, near its place
    (``KNOCK_OUT_XY``) at a random yaw (+-45 deg), at rest; the robot stays as it is. The states a switcher meets
    when a tool is dropped, for F to learn that the next stage cannot start from them."""
    name = env.target_object
    height = TOOL_SPECS[name].bounding_box[2]
    xy = TOOL_XY + rng.uniform(-KNOCK_OUT_XY, KNOCK_OUT_XY, size=2)
    env.objects.set_pose(env.context, name, RigidTransform(RollPitchYaw(0.0, 0.0, rng.uniform(-np.pi / 4, np.pi / 4)),
                                                           [*xy, TABLE_TOP + height / 2 + 0.002]), frozen=False)
