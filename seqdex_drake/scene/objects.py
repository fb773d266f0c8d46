"""Bookkeeping of a station's loose objects: placing, parking, freezing, waking and restoring piles.

:class:`SceneObjects` edits a station context between control steps (it is not a System: collision
filters and body masses live in the SceneGraph and plant contexts, which no event of another system may
write). Every call costs microseconds to a few milliseconds; restoring a cached pile is a state write.

Collision filters are edited incrementally with *persistent* declarations on the context: freezing objects N
excludes the pairs (N, static + frozen), waking objects W allows the pairs (W, static + previously frozen)
again. SceneGraph stores filters as a dense table over all geometries, and every *transient* declaration
(``ApplyTransient`` / ``RemoveDeclaration``) copies or rebuilds the whole table (70-100 ms with the 72-block
pile's ~800 geometries), while a persistent declaration touches only the pairs it names (microseconds for
one block). The effective filter state is the same: the plant's own filters, plus every pair within the
static geometries and the frozen objects' geometries.
"""

from __future__ import annotations

import fnmatch
import math

import numpy as np
from pydrake.geometry import CollisionFilterDeclaration, GeometrySet
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialVelocity
from pydrake.systems.framework import Context, Diagram

from seqdex_drake.robots.allegro import FINGERTIP_FRAMES, PALM_BODY, p_PalmPc_Palm
from seqdex_drake.scenario import Scenario
from seqdex_drake.scene.freezing import FrozenSet, ObjectBody

#: Parking lot for unused objects: a row 1.5 m behind the robot, off the table, frozen in mid-air.
PARKING_ORIGIN = np.array([-1.5, -1.0, 0.3])
PARKING_PITCH = 0.15


class SceneObjects:
    """Places, freezes and wakes the loose objects of one station (see ``scene/freezing.py``).

    Args:
        station: the Diagram from :func:`~seqdex_drake.station.MakeStation`.
        scenario: the scenario it was built from.
    """

    def __init__(self, station: Diagram, scenario: Scenario):
        self.station = station
        self.scenario = scenario
        self.plant = station.GetSubsystemByName("plant")
        self.scene_graph = station.GetSubsystemByName("scene_graph")
        self.freezer = station.GetSubsystemByName("object_freezer")
        self.names = list(scenario.objects)
        self.bodies = [ObjectBody(self.plant, name) for name in self.names]
        self._index = {name: i for i, name in enumerate(self.names)}
        # Indices of each object's free-body positions (n, 7) in q and translational velocities (n, 3) in v.
        self._q_index = np.array([b.floating_positions_start() + np.arange(7) for b in self.bodies],
                                 dtype=int).reshape(-1, 7)
        self._v_translational_index = np.array([b.floating_velocities_start_in_v() + 3 + np.arange(3)
                                                for b in self.bodies], dtype=int).reshape(-1, 3)
        # The same positions and velocities in the plant state [q, v], per object (the wake check reads both).
        self._x_index = np.c_[self._q_index[:, 4:], self.plant.num_positions() + self._v_translational_index].tolist()
        self._geometries = [self.plant.GetCollisionGeometriesForBody(b) for b in self.bodies]
        self._static = [g for body in self.plant.GetBodiesWeldedTo(self.plant.world_body())
                        for g in self.plant.GetCollisionGeometriesForBody(body)]
        self._base_filtered = self._plant_filtered_pairs()
        self._never_wake = np.array([any(fnmatch.fnmatch(name, pattern) for pattern in scenario.freeze.never_wake)
                                     for name in self.names], dtype=bool).reshape(len(self.names))
        self._still_ticks = [0] * len(self.names)  # Per object, as Python numbers (the wake check's arithmetic).
        self._last_speed = [0.0] * len(self.names)
        hand = self.plant.GetModelInstanceByName("allegro")
        self._tip_frames = [self.plant.GetFrameByName(f, hand) for f in FINGERTIP_FRAMES]
        # Body indices as ints (the contact loop of _touched hashes ints, not BodyIndex objects).
        self._robot_bodies = {int(b) for b in self.plant.GetBodyIndices(hand)} | {
            int(b) for b in self.plant.GetBodyIndices(self.plant.GetModelInstanceByName("franka"))}
        self._object_of_body = {int(body.index()): i for i, body in enumerate(self.bodies)}
        self._palm_frame = self.plant.GetBodyByName(PALM_BODY, hand).body_frame()
        self._last_root: tuple = (None, None, None)  # (root, plant context, freezer context) of the last update.

    # ----------------------------------------------------------------------------------------- access
    def index(self, name: str) -> int:
        """Position of object ``name`` in ``scenario.objects``; clear error for unknown names."""
        if name not in self._index:
            raise KeyError(f"unknown object '{name}'; this station's objects: {', '.join(self.names)}")
        return self._index[name]

    def _contexts(self, root: Context):
        return (self.plant.GetMyMutableContextFromRoot(root),
                self.scene_graph.GetMyMutableContextFromRoot(root),
                self.freezer.GetMyMutableContextFromRoot(root))

    def positions(self, root: Context) -> np.ndarray:
        """(n, 7) free-body positions [quaternion wxyz, xyz] of all objects."""
        return self.plant.GetPositions(self.plant.GetMyContextFromRoot(root))[self._q_index]

    def frozen_mask(self, root: Context) -> np.ndarray:
        """Boolean mask of frozen objects."""
        return self.freezer.frozen_set(self.freezer.GetMyContextFromRoot(root)).frozen.copy()

    def fallen(self, root: Context, below: float, plant_state: np.ndarray | None = None) -> list[str]:
        """The awake objects whose origin is below world height ``below`` [m]: knocked off the table, where
        nothing catches them (the floor is not modelled), they would fall for ever and blow the state up.
        ``plant_state``: the plant's [q, v], where the caller has it already."""
        x = self.plant.GetPositions(self.plant.GetMyContextFromRoot(root)) if plant_state is None else plant_state
        z = x[self._q_index[:, 6]].tolist()
        frozen = self.freezer.frozen_set(self.freezer.GetMyContextFromRoot(root)).frozen.tolist()
        return [name for name, height, is_frozen in zip(self.names, z, frozen, strict=True)
                if height < below and not is_frozen]

    def frozen_names(self, root: Context) -> list[str]:
        return [n for n, f in zip(self.names, self.frozen_mask(root), strict=True) if f]

    # ---------------------------------------------------------------------------------------- placing
    def set_positions(self, root: Context, q_objects: np.ndarray, frozen: np.ndarray | None = None) -> None:
        """Sets all objects' free-body positions (zero velocity), then the frozen set (default: unchanged)."""
        q_objects = np.asarray(q_objects, dtype=float).reshape(len(self.names), 7)
        plant_context, _, _ = self._contexts(root)
        q = self.plant.GetPositions(plant_context)
        v = self.plant.GetVelocities(plant_context)
        for body, q_body in zip(self.bodies, q_objects, strict=True):
            start = body.floating_positions_start()
            q[start:start + 7] = q_body
            v[body.floating_velocities_start_in_v():body.floating_velocities_start_in_v() + 6] = 0.0
        self.plant.SetPositions(plant_context, q)
        self.plant.SetVelocities(plant_context, v)
        self._last_speed = [0.0] * len(self.names)  # At rest: no impact of an earlier motion is pending.
        self.set_frozen(root, self.frozen_mask(root) if frozen is None else frozen)

    def set_pose(self, root: Context, name: str, X_WB: RigidTransform, frozen: bool = False) -> None:
        """Places one object at ``X_WB`` at rest and freezes or wakes it."""
        plant_context, _, _ = self._contexts(root)
        body = self.bodies[self.index(name)]
        self.plant.SetFreeBodyPose(plant_context, body, X_WB)
        self.plant.SetFreeBodySpatialVelocity(plant_context, body, SpatialVelocity.Zero())
        self._last_speed[self.index(name)] = 0.0  # At rest: no impact of an earlier motion is pending.
        mask = self.frozen_mask(root)
        mask[self.index(name)] = frozen
        self.set_frozen(root, mask)

    def parking_pose(self, name: str) -> RigidTransform:
        """The parking pose of object ``name``: a slot in a row off the table."""
        return RigidTransform(PARKING_ORIGIN + [0.0, PARKING_PITCH * self.index(name), 0.0])

    def park(self, root: Context, names: list[str] | None = None) -> None:
        """Moves objects (default: all) to their parking slots, frozen."""
        for name in self.names if names is None else names:
            self.set_pose(root, name, self.parking_pose(name), frozen=True)

    # --------------------------------------------------------------------------------------- freezing
    def forget_motion(self) -> None:
        """Clears the wake/sleep bookkeeping's memory of past motion (each object's still ticks and its speed at
        the last :meth:`update`), as in a new :class:`SceneObjects`: an environment reset calls it, so that
        nothing of the previous episode decides what wakes or sleeps in the next one.

        (:meth:`set_frozen` clears the still ticks only: :meth:`update` calls it mid-episode, where the speeds
        of the check it just made must stay, for the next check's "fast now or at the last check".)"""
        self._still_ticks = [0] * len(self.names)
        self._last_speed = [0.0] * len(self.names)

    def get_state(self, root: Context) -> dict:
        """Everything besides the plant state that the objects' future depends on (for exact restores)."""
        frozen_set = self.freezer.frozen_set(self.freezer.GetMyContextFromRoot(root))
        return {"frozen": frozen_set.frozen.copy(), "q_pin": frozen_set.q_pin.copy(),
                "still_ticks": np.array(self._still_ticks, dtype=int), "last_speed": np.array(self._last_speed)}

    def set_state(self, root: Context, state: dict) -> None:
        """Restores :meth:`get_state` output (after the plant state has been restored)."""
        self.set_frozen(root, state["frozen"], q_pin=state["q_pin"])
        self._still_ticks = [int(t) for t in state["still_ticks"]]
        self._last_speed = [float(v) for v in state["last_speed"]]

    def set_frozen(self, root: Context, frozen: np.ndarray, q_pin: np.ndarray | None = None) -> None:
        """Freezes exactly the objects in mask ``frozen`` at their current poses (or ``q_pin``); wakes the others."""
        frozen = np.asarray(frozen, dtype=bool).reshape(len(self.names))
        plant_context, scene_graph_context, freezer_context = self._contexts(root)
        for body, is_frozen in zip(self.bodies, frozen, strict=True):
            mass = body.default_mass() * (self.scenario.freeze.mass_scale if is_frozen else 1.0)
            if body.get_mass(plant_context) != mass:
                body.SetMass(plant_context, mass)
        self._update_filters(scene_graph_context, self.freezer.frozen_set(freezer_context).frozen, frozen)
        pins = self.positions(root) if q_pin is None else np.array(q_pin, dtype=float)
        self.freezer.set_frozen_set(freezer_context, FrozenSet(frozen.copy(), pins))
        self._still_ticks = [0] * len(self.names)

    def redeclare_filters(self, root: Context) -> None:
        """Declares the frozen set's collision filters again in full (after ``SceneGraph.ChangeShape``, which
        drops the changed geometries' filters in the context)."""
        scene_graph_context = self.scene_graph.GetMyMutableContextFromRoot(root)
        frozen = self.frozen_mask(root)
        declaration = CollisionFilterDeclaration()
        if frozen.any():
            declaration.ExcludeWithin(GeometrySet(self._static + self._object_geometries(np.flatnonzero(frozen))))
        for i, others in self._base_filtered.items():
            declaration.ExcludeBetween(GeometrySet(self._geometries[i]), GeometrySet(others))
        self.scene_graph.collision_filter_manager(scene_graph_context).Apply(declaration)

    def _object_geometries(self, indices) -> list:
        return [g for i in indices for g in self._geometries[i]]

    def _update_filters(self, scene_graph_context: Context, before: np.ndarray, after: np.ndarray) -> None:
        """Edits the context's collision filters from frozen set ``before`` to ``after`` (see the module doc)."""
        woken, newly_frozen = np.flatnonzero(before & ~after), np.flatnonzero(after & ~before)
        if not woken.size and not newly_frozen.size:
            return
        declaration = CollisionFilterDeclaration()
        if woken.size:
            declaration.AllowBetween(GeometrySet(self._object_geometries(woken)),
                                     GeometrySet(self._static + self._object_geometries(np.flatnonzero(before))))
            for i in woken:  # Pairs the plant itself filters stay filtered (none in the shipped models).
                if i in self._base_filtered:
                    declaration.ExcludeBetween(GeometrySet(self._geometries[i]), GeometrySet(self._base_filtered[i]))
        if newly_frozen.size:
            declaration.ExcludeBetween(GeometrySet(self._object_geometries(newly_frozen)),
                                       GeometrySet(self._static + self._object_geometries(np.flatnonzero(after))))
        self.scene_graph.collision_filter_manager(scene_graph_context).Apply(declaration)

    def _plant_filtered_pairs(self) -> dict[int, list]:
        """Object index -> static and other objects' geometries that the model itself filters against it.

        Checked per body (one geometry each for objects: the plant filters whole bodies) in the model."""
        inspector = self.scene_graph.model_inspector()
        first = [geometries[0] if geometries else None for geometries in self._geometries]
        filtered: dict[int, list] = {}
        for i, g in enumerate(first):
            if g is None:
                continue
            others = [h for h in self._static if inspector.CollisionFiltered(g, h)]
            others += [h for j, f in enumerate(first) if j != i and f is not None and inspector.CollisionFiltered(g, f)
                       for h in self._geometries[j]]
            if others:
                filtered[i] = others
        return filtered

    def freeze_far_from(self, root: Context, p_WF: np.ndarray, radius: float | None = None) -> None:
        """Freezes every object whose origin is farther than ``radius`` (default: scenario's) from ``p_WF``."""
        radius = self.scenario.freeze.active_radius if radius is None else radius
        distance = np.linalg.norm(self.positions(root)[:, 4:] - np.asarray(p_WF), axis=1)
        self.set_frozen(root, distance > radius)

    def hand_points(self, root: Context) -> np.ndarray:
        """(5, 3) world positions of the four fingertips (index, middle, ring, thumb) and the palm centre."""
        plant_context = self.plant.GetMyContextFromRoot(root)
        tips = [f.CalcPoseInWorld(plant_context).translation() for f in self._tip_frames]
        return np.array(tips + [self._palm_frame.CalcPoseInWorld(plant_context) @ p_PalmPc_Palm])

    def update(self, root: Context, hand: np.ndarray | None = None, plant_state: list[float] | None = None
               ) -> list[str]:
        """Wakes frozen objects the hand touches or comes near, or that a fast-moving object touches;
        freezes again objects that have rested, away from the hand, for ``freeze.sleep_ticks`` steps.

        Call once per control step. Returns the names of the objects woken. Touches come from the plant's
        contact results, which with sampled output ports are those of its last step: after editing the state
        without a step, refresh them first (``station.RefreshSampledOutputs``). ``hand``: the
        :meth:`hand_points` of the current state (an array or rows of floats), and ``plant_state``: the
        plant's [q, v] as a list of floats, where the caller has them already.

        The check runs object by object in plain float arithmetic: a handful of objects in most scenes, and
        right after a physics step, where this runs with the caches cold, every distinct numpy function
        would cost microseconds.
        """
        config = self.scenario.freeze
        if self._last_root[0] is not root:  # The subsystem contexts of the root, looked up once per root.
            self._last_root = (root, self.plant.GetMyContextFromRoot(root), self.freezer.GetMyContextFromRoot(root))
        _, plant_context, freezer_context = self._last_root
        frozen = self.freezer.frozen_set(freezer_context).frozen  # Read only (set_frozen replaces the set).
        x = self.plant.GetPositionsAndVelocities(plant_context).tolist() if plant_state is None else plant_state
        hand = self.hand_points(root) if hand is None else hand
        hand = hand.tolist() if isinstance(hand, np.ndarray) else hand
        wake_radius2, ticks, speeds, positions = config.wake_radius**2, list(self._still_ticks), [], []
        sleep_ticks = config.sleep_ticks if config.enabled else 0
        wake, sleep, moving, idle, reach = [], [], [], [], False
        never_wake = self._never_wake.tolist()
        for i, (is_frozen, (a, b, c, d, e, f), v_last) in enumerate(zip(frozen.tolist(), self._x_index,
                                                                          self._last_speed, strict=True)):
            px, py, pz, vx, vy, vz = x[a], x[b], x[c], x[d], x[e], x[f]
            positions.append((px, py, pz))
            v = math.sqrt(vx * vx + vy * vy + vz * vz)
            speeds.append(v)
            d2 = math.inf  # Squared distance to the nearest hand point.
            for hx, hy, hz in hand:
                dx, dy, dz = px - hx, py - hy, pz - hz
                e2 = dx * dx + dy * dy + dz * dz
                if e2 < d2:
                    d2 = e2
            if is_frozen:
                ticks[i] = 0
                if never_wake[i]:
                    continue
                if d2 < wake_radius2:
                    wake.append(i)
                elif d2 < 0.2**2:  # Within reach of the hand (it spans ~0.25 m): maybe touched.
                    reach = True
                else:
                    idle.append(i)
                continue
            # Fast now or at the last check: an impact is over (slow again) by the end of the step it happens in.
            if max(v, v_last) > config.wake_speed:
                moving.append(i)
            if v < config.sleep_speed and d2 >= wake_radius2:  # Resting, away from the hand.
                ticks[i] += 1
                if 0 < sleep_ticks <= ticks[i]:
                    sleep.append(i)
            else:
                ticks[i] = 0
        self._last_speed = speeds
        if moving and idle and not reach:  # A frozen object within a moving object's size of it may be touched.
            movers = [positions[j] for j in moving]
            reach = any((ox - mx) ** 2 + (oy - my) ** 2 + (oz - mz) ** 2 < 0.2**2
                        for ox, oy, oz in (positions[i] for i in idle) for mx, my, mz in movers)
        if reach:  # Read the contacts (a Python loop over them) only then.
            is_moving = np.zeros(len(self.names), dtype=bool)
            is_moving[moving] = True
            touched = np.flatnonzero(frozen & ~self._never_wake & self._touched(plant_context, frozen, is_moving)
                                     ).tolist()
            wake = sorted(set(wake).union(touched))
        if not wake and not sleep:
            self._still_ticks = ticks
            return []
        new_frozen = frozen.copy()
        new_frozen[wake], new_frozen[sleep] = False, True
        self.set_frozen(root, new_frozen)
        for i in sleep:
            ticks[i] = 0
        self._still_ticks = ticks
        return [self.names[i] for i in wake]

    def _touched(self, plant_context: Context, frozen: np.ndarray, moving: np.ndarray) -> np.ndarray:
        """Frozen objects in contact with the robot or with a moving object (the current state's contacts).

        The contact results are the plant's sampled outputs (its last step's): reading them costs no solve. The
        loop runs over every contact (~100 in Search's pile), on Python ints and lists.
        """
        touched, is_frozen, is_moving = [False] * len(self.names), frozen.tolist(), moving.tolist()
        object_of_body, robot = self._object_of_body, self._robot_bodies
        results = self.plant.get_contact_results_output_port().Eval(plant_context)
        for k in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(k)
            body_a, body_b = int(info.bodyA_index()), int(info.bodyB_index())
            a, b = object_of_body.get(body_a), object_of_body.get(body_b)
            if a is not None and is_frozen[a] and ((b is not None and is_moving[b]) or body_b in robot):
                touched[a] = True
            if b is not None and is_frozen[b] and ((a is not None and is_moving[a]) or body_a in robot):
                touched[b] = True
        return np.array(touched)

    def robot_bodies_touching(self, plant_context: Context, name: str) -> int:
        """How many distinct robot bodies touch object ``name`` (the plant's sampled contact results): a pinch or
        a grasp needs at least two, on opposite sides."""
        body, robot = int(self.bodies[self.index(name)].index()), self._robot_bodies
        results = self.plant.get_contact_results_output_port().Eval(plant_context)
        touching = set()
        for k in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(k)
            a, b = int(info.bodyA_index()), int(info.bodyB_index())
            if a == body and b in robot:
                touching.add(b)
            elif b == body and a in robot:
                touching.add(a)
        return len(touching)

    def touches_robot(self, plant_context: Context, name: str) -> bool:
        """Whether object ``name`` is in contact with the robot (the plant's sampled contact results: its last
        step's, as :meth:`update` reads them)."""
        return self.robot_bodies_touching(plant_context, name) > 0
