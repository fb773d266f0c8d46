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


# _quat_to_matrices: R's nine entries are (1 -) 2 * (product_a +- product_b) of the quaternion's components.
_PRODUCTS = np.array([(0, 1), (0, 2), (0, 3), (1, 1), (1, 2), (1, 3), (2, 2), (2, 3), (3, 3)])  # wx .. zz
_WX, _WY, _WZ, _XX, _XY, _XZ, _YY, _YZ, _ZZ = range(9)
_ENTRY_A = np.array([_YY, _XY, _XZ, _XY, _XX, _YZ, _XZ, _YZ, _XX])
_ENTRY_B = np.array([_ZZ, _WZ, _WY, _WZ, _ZZ, _WX, _WY, _WX, _YY])
_ENTRY_SIGN = np.array([1.0, -1.0, 1.0, 1.0, 1.0, -1.0, -1.0, 1.0, 1.0])
_DIAGONAL = np.array([0, 4, 8])


def _quat_to_matrices(q: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotation matrices of (n, 4) unit quaternions [w, x, y, z] (the textbook formula, e.g.
    R[0, 1] = 2 (xy - wz), R[0, 0] = 1 - 2 (yy + zz), evaluated for all entries at once)."""
    products = q[:, _PRODUCTS[:, 0]] * q[:, _PRODUCTS[:, 1]]
    R = 2 * (products[:, _ENTRY_A] + products[:, _ENTRY_B] * _ENTRY_SIGN)  # a + (-1.0 * b) == a - b exactly.
    R[:, _DIAGONAL] = 1 - R[:, _DIAGONAL]
    # C order, as np.stack gives: einsum's summation order (so its last bit) follows its operands' memory layout.
    return np.ascontiguousarray(R.reshape(-1, 3, 3))


def _cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (n, 3) arrays: ``np.cross``'s arithmetic without its per-call overhead."""
    out = np.empty((len(a), 3))
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


@dataclasses.dataclass
class _Pinned:
    """What the pin force needs of one frozen set that does not change between plant steps."""

    q_index: np.ndarray
    v_index: np.ndarray
    force_index: np.ndarray
    mass: np.ndarray
    anti_gravity: np.ndarray
    p_BoBcm_B: np.ndarray
    I_Bcm_B: np.ndarray
    p_WBcm0: np.ndarray
    w0: np.ndarray
    u0: np.ndarray


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
        self._pinned_memo: tuple = (None, None)

    def frozen_set(self, context) -> FrozenSet:
        """The current frozen set (read-only view)."""
        return context.get_abstract_state(self._state_index).get_value()

    def set_frozen_set(self, context, frozen: FrozenSet) -> None:
        """Replaces the frozen set in ``context`` (the freezer's own context)."""
        context.get_mutable_abstract_state(self._state_index).set_value(frozen)

    def _pinned(self, frozen: FrozenSet) -> _Pinned | None:
        """The frozen set's constant terms, recomputed only when the set or its pins change (the plant steps
        several times per control step with the same set). A memo keyed on the values, so any context may ask."""
        key = (frozen.frozen.tobytes(), frozen.q_pin.tobytes())
        if self._pinned_memo[0] != key:
            index = np.flatnonzero(frozen.frozen)
            pinned = None
            if index.size:
                pin = frozen.q_pin[index]
                p_BoBcm_B = self._p_BoBcm_B[index]
                R_WB0 = _quat_to_matrices(pin[:, :4])
                pinned = _Pinned(
                    q_index=self._q_start[index, None] + np.arange(7),
                    v_index=self._nq + self._v_start[index, None] + np.arange(6),
                    force_index=self._v_start[index, None] + np.arange(6), mass=self._mass[index, None],
                    anti_gravity=self._anti_gravity[index], p_BoBcm_B=p_BoBcm_B, I_Bcm_B=self._I_Bcm_B[index],
                    p_WBcm0=pin[:, 4:] + np.einsum("nij,nj->ni", R_WB0, p_BoBcm_B), w0=pin[:, :1], u0=pin[:, 1:4])
            self._pinned_memo = (key, pinned)
        return self._pinned_memo[1]

    def _calc_force(self, context, output: BasicVector) -> None:
        force = np.zeros(self._nv)
        pinned = self._pinned(self.frozen_set(context))
        if pinned is not None:
            x = self.get_input_port().Eval(context)
            q, v = x[pinned.q_index], x[pinned.v_index]
            R_WB = _quat_to_matrices(q[:, :4] / np.linalg.norm(q[:, :4], axis=1, keepdims=True))
            p_BoBcm_W = np.einsum("nij,nj->ni", R_WB, pinned.p_BoBcm_B)
            # The pin acts at the centre of mass, where translation and rotation decouple.
            p_WBcm = q[:, 4:] + p_BoBcm_W
            w_WB = v[:, :3]
            v_WBcm = v[:, 3:] + _cross_rows(w_WB, p_BoBcm_W)
            # Rotation error as a small-angle vector in W: 2 * vec(q_pin * conj(q)), sign-fixed.
            w0, u0 = pinned.w0, pinned.u0
            w1, u1 = q[:, :1], -q[:, 1:4]
            err_w = w0 * w1 - np.sum(u0 * u1, axis=1, keepdims=True)
            err_u = w0 * u1 + w1 * u0 + _cross_rows(u0, u1)
            theta = 2.0 * np.sign(err_w + 1e-12) * err_u
            I_Bcm_W = np.einsum("nij,njk,nlk->nil", R_WB, pinned.I_Bcm_B, R_WB)
            omega = PIN_OMEGA
            f_Bcm_W = pinned.mass * (omega**2 * (pinned.p_WBcm0 - p_WBcm) - 2 * omega * v_WBcm)
            f_Bcm_W += pinned.anti_gravity
            tau_Bcm_W = np.einsum("nij,nj->ni", I_Bcm_W, omega**2 * theta - 2 * omega * w_WB)
            # Shift the spatial force from Bcm to Bo, where the floating joint's generalized forces act.
            tau_Bo_W = tau_Bcm_W + _cross_rows(p_BoBcm_W, f_Bcm_W)
            force[pinned.force_index] = np.concatenate([tau_Bo_W, f_Bcm_W], axis=1)
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
