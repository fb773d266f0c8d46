"""Freezing loose objects: parked objects and far-away blocks of a pile cost (almost) nothing.

A frozen object is still a free body of the plant, but

- its collisions with other frozen objects and with the static scene are filtered out in the SceneGraph
  context, so the contact solver never sees the pile's deep layers, the box floor or the table under them;
- the :class:`ObjectFreezer` system holds it at its pinned pose with anti-gravity plus a critically damped
  spring, linearized about the pin into one affine map of the plant state (a batched product per plant
  step, fed to ``applied_generalized_force``);
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


def _skew(a: np.ndarray) -> np.ndarray:
    """(n, 3, 3) cross-product matrices: ``_skew(a)[k] @ b == np.cross(a[k], b)``."""
    S = np.zeros((len(a), 3, 3))
    S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -a[:, 2], a[:, 1], -a[:, 0]
    S[:, 1, 0], S[:, 2, 0], S[:, 2, 1] = a[:, 2], -a[:, 1], a[:, 0]
    return S


def pin_force_map(q_pin: np.ndarray, mass: np.ndarray, p_BoBcm_B: np.ndarray, I_Bcm_B: np.ndarray,
                  gravity: np.ndarray, omega: float = PIN_OMEGA) -> tuple[np.ndarray, np.ndarray]:
    """The pin's generalized force as an affine map of the free-body state, linearized about the pin.

    The pin acts at the centre of mass: a critically damped spring of natural frequency ``omega`` on the
    centre of mass's position and on the rotation error (the small-angle vector ``2 vec(q_pin * conj(q))``),
    plus anti-gravity. Scaled by the mass and the rotational inertia about the centre of mass (in W), it is
    then shifted to the body origin, where the floating joint's generalized forces [tau_Bo_W, f_Bo_W] act.

    The quaternion error is exactly linear in q (q on the pin's side of the double cover, as a frozen object's
    quaternion stays). The centre of mass's offset ``R(q) p_BoBcm_B`` enters to first
    order (its Jacobian in q, taken on the unit sphere so that it ignores q's norm), and the inertia in W is taken
    at the pin. A frozen object stays within micrometres and microradians of its pin, so the force differs from
    the exact one by a relative O(deviation) ~ 1e-5 (``tests/test_freezing.py``).

    Args:
        q_pin: (n, 7) pinned positions [qw, qx, qy, qz, x, y, z] (unit quaternions).
        mass: (n,) masses (already scaled), p_BoBcm_B: (n, 3), I_Bcm_B: (n, 3, 3) about the centre of mass.
        gravity: the gravity vector (3,).

    Returns:
        (A, b): (n, 6, 13) and (n, 6) with [tau_Bo_W, f_Bo_W] = A @ [q (7), w_WB (3), v_WBo (3)] + b.
    """
    n = len(q_pin)
    m = np.asarray(mass, dtype=float).reshape(n, 1, 1)
    w0, u0 = q_pin[:, 0], q_pin[:, 1:4]
    R = _quat_to_matrices(q_pin[:, :4])
    c = np.einsum("nij,nj->ni", R, p_BoBcm_B)  # p_BoBcm_W at the pin.
    I_W = np.einsum("nij,njk,nlk->nil", R, I_Bcm_B, R)
    C, eye = _skew(c), np.broadcast_to(np.eye(3), (n, 3, 3))
    # d(R(q) p_BoBcm_B)/dq at the pin, from R(q) c_B = ((w^2 - u.u) c_B + 2 (u.c_B) u + 2 w u x c_B) / |q|^2.
    c_B = p_BoBcm_B
    J = np.zeros((n, 3, 4))
    J[:, :, 0] = 2 * w0[:, None] * c_B + 2 * np.cross(u0, c_B) - 2 * w0[:, None] * c
    J[:, :, 1:4] = (2 * (np.einsum("ni,nj->nij", u0, c_B) + np.einsum("ni,ni->n", u0, c_B)[:, None, None] * eye)
                    - 2 * np.einsum("ni,nj->nij", c_B, u0) - 2 * w0[:, None, None] * _skew(c_B)
                    - 2 * np.einsum("ni,nj->nij", c, u0))
    # Force at the centre of mass: m (omega^2 (p_WBcm0 - p_WBcm) - 2 omega v_WBcm) - m g, where
    # p_WBcm = p_WBo + c and v_WBcm = v_WBo + w x c = v_WBo - C w.
    force = np.zeros((n, 3, 13))
    force[:, :, :4] = -m * omega**2 * J  # J q_pin = 0: the offset's change is J q.
    force[:, :, 4:7] = -m * omega**2 * eye
    force[:, :, 7:10] = 2 * omega * m * C
    force[:, :, 10:13] = -2 * omega * m * eye
    force_0 = (m[:, :, 0] * omega**2) * q_pin[:, 4:] - np.outer(mass, gravity)  # p_WBcm0 - c = p_WBo0.
    # Torque at the centre of mass: I_W (omega^2 theta - 2 omega w), theta = 2 (w_q u0 - w0 u - u0 x u).
    theta = np.zeros((n, 3, 7))
    theta[:, :, 0] = 2 * u0
    theta[:, :, 1:4] = -2 * (w0[:, None, None] * eye + _skew(u0))
    torque = np.zeros((n, 3, 13))
    torque[:, :, :7] = omega**2 * I_W @ theta
    torque[:, :, 7:10] = -2 * omega * I_W
    # tau_Bo = tau_Bcm + c x f, to first order c0 x f + (J q) x f_pin, with f_pin = -m g the force at the pin.
    torque[:, :, :4] -= _skew(-np.outer(mass, gravity)) @ J
    A = np.concatenate([torque + C @ force, force], axis=1)
    b = np.concatenate([np.einsum("nij,nj->ni", C, force_0), force_0], axis=1)
    return A, b


@dataclasses.dataclass
class _Pinned:
    """What the pin force needs of one frozen set that does not change between plant steps."""

    x_index: np.ndarray
    """(n, 13) indices of each frozen object's [q (7), v (6)] in the plant state."""
    force_index: np.ndarray
    """(n, 6) indices of each frozen object's generalized forces."""
    A: np.ndarray
    b: np.ndarray


class ObjectFreezer(LeafSystem):
    """Applies hold-in-place generalized forces to frozen free-body objects.

    Input ``plant_state`` is the full plant state; output ``generalized_force`` (size nv) goes to the
    plant's ``applied_generalized_force`` port. Abstract state: a :class:`FrozenSet`. The force is the affine
    map of :func:`pin_force_map`, built once per frozen set, so a plant step costs one batched product.

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
        self._gravity = np.asarray(plant.gravity_field().gravity_vector(), dtype=float)
        self._mass = np.array([b.default_mass() for b in object_bodies]) * mass_scale
        self._p_BoBcm_B = np.array([b.default_com() for b in object_bodies]).reshape(n, 3)
        # Rotational inertia about the centre of mass, in the body frame, scaled like the mass.
        self._I_Bcm_B = np.array([mass_scale * b.default_spatial_inertia().Shift(b.default_com())
                                  .CalcRotationalInertia().CopyToFullMatrix3() for b in object_bodies]).reshape(n, 3, 3)
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
        """The frozen set's force map, recomputed only when the set or its pins change (the plant steps
        several times per control step with the same set). A memo keyed on the values, so any context may ask."""
        key = (frozen.frozen.tobytes(), frozen.q_pin.tobytes())
        if self._pinned_memo[0] != key:
            index = np.flatnonzero(frozen.frozen)
            pinned = None
            if index.size:
                pin = frozen.q_pin[index]
                A, b = pin_force_map(np.c_[pin[:, :4] / np.linalg.norm(pin[:, :4], axis=1, keepdims=True),
                                           pin[:, 4:]], self._mass[index], self._p_BoBcm_B[index],
                                     self._I_Bcm_B[index], self._gravity)
                x_index = np.c_[self._q_start[index, None] + np.arange(7),
                                self._nq + self._v_start[index, None] + np.arange(6)]
                pinned = _Pinned(x_index=x_index, force_index=self._v_start[index, None] + np.arange(6),
                                 A=A, b=b)
            self._pinned_memo = (key, pinned)
        return self._pinned_memo[1]

    def _calc_force(self, context, output: BasicVector) -> None:
        force = np.zeros(self._nv)
        pinned = self._pinned(self.frozen_set(context))
        if pinned is not None:
            x = self.get_input_port().Eval(context)[pinned.x_index]
            force[pinned.force_index] = np.matmul(pinned.A, x[:, :, None])[:, :, 0] + pinned.b
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
