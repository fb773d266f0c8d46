"""Freezing loose objects: parked objects and far-away blocks of a pile cost (almost) nothing.

A frozen object is still a free body of the plant, but

- its collisions with other frozen objects and with the static scene are filtered out in the SceneGraph
  context, so the contact solver never sees the pile's deep layers, the box floor or the table under them;
- the :class:`ObjectFreezer` system holds it at its pinned pose with anti-gravity plus a critically damped
  spring (vectorized numpy over the plant state, fed to ``applied_generalized_force``);
- its mass is scaled up, so a dynamic object resting on it deflects it by micrometres.

Dynamic objects, the hand and the arm still collide with frozen objects, which behave as static supports.
The bookkeeping (which objects are frozen, collision filters, masses, waking) lives in
:class:`seqdex_drake.scene.objects.SceneObjects`, which edits a context between control steps. Drake's
joint locking would be the natural tool, but in Drake 1.51.1 any locked floating joint crashes the
simulation as soon as a free body touches the world (see ``tests/test_freezing.py``'s docstring).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.framework import BasicVector, DiagramBuilder, LeafSystem

#: Natural frequency (rad/s) of the pin spring. With 2 ms steps, omega * dt = 0.12 keeps the explicit
#: spring well inside its stability region; critically damped.
PIN_OMEGA = 60.0


@dataclasses.dataclass
class FrozenSet:
    """The freezer's abstract state: which objects are frozen and where they are pinned."""

    frozen: np.ndarray
    """Boolean mask over the freezer's objects."""
    q_pin: np.ndarray
    """(n, 7) pinned free-body positions [qw, qx, qy, qz, x, y, z] in the world."""


def _quat_to_matrices(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


class ObjectFreezer(LeafSystem):
    """Applies hold-in-place generalized forces to frozen free-body objects.

    Input ``plant_state`` is the full plant state; output ``generalized_force`` (size nv) goes to the
    plant's ``applied_generalized_force`` port. Abstract state: a :class:`FrozenSet`.

    Args:
        plant: the finalized station plant.
        object_bodies: the bodies (one per object instance, each on a quaternion floating joint).
        mass_scale: the frozen-mass multiplier that :class:`SceneObjects` applies; the pin gains use it.
    """

    def __init__(self, plant: MultibodyPlant, object_bodies: list, mass_scale: float):
        super().__init__()
        n = len(object_bodies)
        self._nq, self._nv = plant.num_positions(), plant.num_velocities()
        self._q_start = np.array([b.floating_positions_start() for b in object_bodies], dtype=int)
        self._v_start = np.array([b.floating_velocities_start_in_v() for b in object_bodies], dtype=int)
        gravity = plant.gravity_field().gravity_vector()
        self._mass = np.array([b.default_mass() for b in object_bodies]) * mass_scale
        self._p_BoBcm_B = np.array([b.default_com() for b in object_bodies]).reshape(n, 3)
        # Rotational inertia about the centre of mass, in the body frame, scaled like the mass.
        self._I_Bcm_B = np.array([mass_scale * b.default_spatial_inertia().Shift(b.default_com())
                                  .CalcRotationalInertia().CopyToFullMatrix3() for b in object_bodies]).reshape(n, 3, 3)
        self._anti_gravity = -np.outer(self._mass, gravity)
        self._state_index = self.DeclareAbstractState(
            AbstractValue.Make(FrozenSet(np.zeros(n, dtype=bool), np.zeros((n, 7)))))
        self.DeclareVectorInputPort("plant_state", self._nq + self._nv)
        self.DeclareVectorOutputPort("generalized_force", self._nv, self._calc_force)

    def frozen_set(self, context) -> FrozenSet:
        """The current frozen set (read-only view)."""
        return context.get_abstract_state(self._state_index).get_value()

    def set_frozen_set(self, context, frozen: FrozenSet) -> None:
        """Replaces the frozen set in ``context`` (the freezer's own context)."""
        context.get_mutable_abstract_state(self._state_index).set_value(frozen)

    def _calc_force(self, context, output: BasicVector) -> None:
        frozen = self.frozen_set(context)
        force = np.zeros(self._nv)
        index = np.flatnonzero(frozen.frozen)
        if index.size:
            x = self.get_input_port().Eval(context)
            q = x[self._q_start[index, None] + np.arange(7)]
            v = x[self._nq + self._v_start[index, None] + np.arange(6)]
            pin = frozen.q_pin[index]
            R_WB = _quat_to_matrices(q[:, :4] / np.linalg.norm(q[:, :4], axis=1, keepdims=True))
            R_WB0 = _quat_to_matrices(pin[:, :4])
            p_BoBcm_B = self._p_BoBcm_B[index]
            p_BoBcm_W = np.einsum("nij,nj->ni", R_WB, p_BoBcm_B)
            # The pin acts at the centre of mass, where translation and rotation decouple.
            p_WBcm = q[:, 4:] + p_BoBcm_W
            p_WBcm0 = pin[:, 4:] + np.einsum("nij,nj->ni", R_WB0, p_BoBcm_B)
            w_WB = v[:, :3]
            v_WBcm = v[:, 3:] + np.cross(w_WB, p_BoBcm_W)
            # Rotation error as a small-angle vector in W: 2 * vec(q_pin * conj(q)), sign-fixed.
            w0, u0 = pin[:, :1], pin[:, 1:4]
            w1, u1 = q[:, :1], -q[:, 1:4]
            err_w = w0 * w1 - np.sum(u0 * u1, axis=1, keepdims=True)
            err_u = w0 * u1 + w1 * u0 + np.cross(u0, u1)
            theta = 2.0 * np.sign(err_w + 1e-12) * err_u
            I_Bcm_W = np.einsum("nij,njk,nlk->nil", R_WB, self._I_Bcm_B[index], R_WB)
            omega = PIN_OMEGA
            f_Bcm_W = self._mass[index, None] * (omega**2 * (p_WBcm0 - p_WBcm) - 2 * omega * v_WBcm)
            f_Bcm_W += self._anti_gravity[index]
            tau_Bcm_W = np.einsum("nij,nj->ni", I_Bcm_W, omega**2 * theta - 2 * omega * w_WB)
            # Shift the spatial force from Bcm to Bo, where the floating joint's generalized forces act.
            tau_Bo_W = tau_Bcm_W + np.cross(p_BoBcm_W, f_Bcm_W)
            force[self._v_start[index, None] + np.arange(3)] = tau_Bo_W
            force[self._v_start[index, None] + 3 + np.arange(3)] = f_Bcm_W
        output.SetFromVector(force)


def AddObjectFreezer(builder: DiagramBuilder, plant: MultibodyPlant, scene_graph, scenario) -> ObjectFreezer:
    """Adds an :class:`ObjectFreezer` over the scenario's objects, wired to the plant."""
    bodies = [ObjectBody(plant, name) for name in scenario.objects]
    freezer = builder.AddSystem(ObjectFreezer(plant, bodies, scenario.freeze.mass_scale))
    freezer.set_name("object_freezer")
    builder.Connect(plant.get_state_output_port(), freezer.get_input_port())
    builder.Connect(freezer.get_output_port(), plant.get_applied_generalized_force_input_port())
    return freezer


def ObjectBody(plant: MultibodyPlant, instance_name: str):
    """The single free body of a loose object model instance."""
    instance = plant.GetModelInstanceByName(instance_name)
    bodies = [plant.get_body(i) for i in plant.GetBodyIndices(instance)]
    free = [b for b in bodies if b.is_floating_base_body()]
    if len(free) != 1:
        raise ValueError(f"object '{instance_name}' must have exactly one free body, found {len(free)}")
    return free[0]
