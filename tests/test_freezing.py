"""Frozen objects: held in place (also under load), cost no contact with the static scene, wake on approach.

Why not Drake's joint locking: in Drake 1.51.1, as soon as any floating joint is locked, a simulation step
in which some free body touches the world (e.g. a block resting on the table) segfaults, with "lagged",
"sap" and "similar" alike and whether or not the locked body has contacts. Freezing therefore uses
anti-gravity plus a pin spring (``ObjectFreezer``), context collision filters and a mass scale instead.
"""

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

from seqdex_drake import LoadScenario
from seqdex_drake.harness import MakeStationHarness
from seqdex_drake.scene.freezing import PIN_OMEGA, pin_force_map
from seqdex_drake.station import RefreshSampledOutputs


def _grasp_harness():
    return MakeStationHarness(LoadScenario("grasp"))


def test_parked_objects_stay_parked():
    harness = _grasp_harness()
    before = harness.objects.positions(harness.context)
    harness.step(30)
    after = harness.objects.positions(harness.context)
    assert np.all(harness.objects.frozen_mask(harness.context))
    assert np.max(np.abs(after[:, 4:] - before[:, 4:])) < 1e-4


def test_frozen_block_supports_a_dynamic_block():
    harness = _grasp_harness()
    floor = 0.6
    harness.objects.set_pose(harness.context, "block_4", RigidTransform([0.25, 0.19, floor + 0.0005]), frozen=True)
    # The 1x3's studs sit at x = -0.03, 0, 0.03; the 1x2's sockets at +-0.015: shift it half a pitch.
    harness.objects.set_pose(harness.context, "block_1", RigidTransform([0.265, 0.19, floor + 0.0375 + 0.0015]))
    frozen_before = harness.objects.positions(harness.context)[3].copy()
    harness.step(60, wake=False)  # With waking, the block landing on it would (rightly) wake it.
    q = harness.objects.positions(harness.context)
    assert abs(q[3, 6] - frozen_before[6]) < 5e-4, "a frozen block moved under load"
    assert abs(q[0, 6] - (floor + 0.0375 + 0.0005)) < 0.002, "the dynamic block did not seat on its frozen support"
    assert np.linalg.norm(q[0, 4:6] - [0.265, 0.19]) < 0.002


def test_frozen_objects_do_not_collide_with_the_static_scene():
    harness = _grasp_harness()
    # A frozen block placed overlapping the box floor generates no contact (filtered); a dynamic one does.
    harness.objects.set_pose(harness.context, "block_2", RigidTransform([0.25, 0.19, 0.59]), frozen=True)
    assert len(harness.port("query_object").ComputePointPairPenetration()) == 0
    harness.objects.set_frozen(harness.context, ~np.isin(harness.objects.names, ["block_2"]))
    assert len(harness.port("query_object").ComputePointPairPenetration()) > 0


def test_update_wakes_blocks_near_the_hand():
    harness = _grasp_harness()
    palm = harness.objects.hand_points(harness.context)[-1]
    harness.objects.set_pose(harness.context, "block_5", RigidTransform(palm + [0, 0, -0.05]), frozen=True)
    woken = harness.objects.update(harness.context)
    assert woken == ["block_5"]
    assert harness.objects.frozen_mask(harness.context).sum() == 7
    assert not harness.objects.frozen_mask(harness.context)[4]
    assert harness.objects.update(harness.context) == []  # Parked blocks far from the hand stay frozen.


def test_a_block_landing_on_a_frozen_block_wakes_it():
    harness = _grasp_harness()
    harness.objects.set_pose(harness.context, "block_4", RigidTransform([0.25, 0.19, 0.6005]), frozen=True)
    harness.objects.set_pose(harness.context, "block_1", RigidTransform([0.265, 0.19, 0.75]))
    harness.step(15)
    assert not harness.objects.frozen_mask(harness.context)[3]


def test_touching_wakes_a_block_beyond_the_wake_radius():
    harness = MakeStationHarness(LoadScenario("grasp", scenario_text="{freeze: {wake_radius: 0.001}}"))
    tip = harness.objects.hand_points(harness.context)[1]  # Middle fingertip (sphere radius 0.012).
    # A 1x4 block lying under the fingertip, its end 2 mm into the fingertip sphere, its centre 7 cm away.
    X_WB = RigidTransform(tip + [0.06 + 0.010, 0.0, -0.0575 / 2])
    harness.objects.set_pose(harness.context, "block_5", X_WB, frozen=True)
    plant = harness.station.GetSubsystemByName("plant")
    # The contact results are the plant's sampled outputs: recompute them for the edited state (a step would).
    RefreshSampledOutputs(plant, plant.GetMyMutableContextFromRoot(harness.context))
    assert harness.objects.update(harness.context) == ["block_5"]  # Only the contact can have woken it.


def _candidates(harness, context=None):
    scene_graph = harness.objects.scene_graph
    context = harness.context if context is None else context
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context))
    return {tuple(sorted((a.get_value(), b.get_value()))) for a, b in query.inspector().GetCollisionCandidates()}


def test_collision_filters_follow_the_frozen_set():
    """After any sequence of freezes, wakes and restores, the collision candidates are the model's own minus
    exactly the pairs within the static geometries and the frozen objects' geometries."""
    harness = _grasp_harness()
    objects = harness.objects
    model = _candidates(harness, harness.diagram.CreateDefaultContext())
    rng = np.random.default_rng(0)
    masks = [rng.random(len(objects.names)) < p for p in (0.5, 0.5, 0.9, 0.1, 0.0, 1.0, 0.5)]
    for mask in [*masks, masks[0]]:
        objects.set_frozen(harness.context, mask)
        filtered = {g.get_value() for g in objects._static + objects._object_geometries(np.flatnonzero(mask))}
        expected = {pair for pair in model if not (pair[0] in filtered and pair[1] in filtered)}
        assert _candidates(harness) == expected
    state = objects.get_state(harness.context)
    objects.set_frozen(harness.context, ~state["frozen"])
    objects.set_state(harness.context, state)
    objects.redeclare_filters(harness.context)  # Idempotent.
    assert _candidates(harness) == expected


def _exact_pin_force(q, v, q_pin, mass, p_BoBcm_B, I_Bcm_B, gravity, omega):
    """The pin force evaluated without linearization, with Drake's rotation and quaternion types (the oracle
    for ``pin_force_map``): [tau_Bo_W, f_Bo_W]."""
    R = RotationMatrix(Quaternion(q[:4] / np.linalg.norm(q[:4]))).matrix()
    R0 = RotationMatrix(Quaternion(q_pin[:4])).matrix()
    c, c0 = R @ p_BoBcm_B, R0 @ p_BoBcm_B
    w, v_Bo = v[:3], v[3:]
    error = Quaternion(q_pin[:4]).multiply(Quaternion(q[:4]).conjugate())  # q is unit to ~1e-10 here.
    theta = 2 * np.sign(error.w()) * error.xyz()
    f = mass * (omega**2 * ((q_pin[4:] + c0) - (q[4:] + c)) - 2 * omega * (v_Bo + np.cross(w, c))) - mass * gravity
    tau = R @ I_Bcm_B @ R.T @ (omega**2 * theta - 2 * omega * w)
    return np.r_[tau + np.cross(c, f), f]


def test_the_linearized_pin_force_matches_the_exact_one_near_the_pin():
    rng = np.random.default_rng(3)
    quat = RollPitchYaw(0.4, -1.1, 2.5).ToQuaternion()
    q_pin = np.r_[quat.wxyz(), 0.3, -0.2, 0.7]
    mass, gravity, com = 0.9, np.array([0.0, 0.0, -9.81]), np.array([0.01, -0.02, 0.015])
    inertia = np.array([[2.0, 0.1, 0.0], [0.1, 3.0, -0.2], [0.0, -0.2, 1.5]]) * 1e-3
    A, b = pin_force_map(q_pin[None], np.array([mass]), com[None], inertia[None], gravity)
    at_pin = _exact_pin_force(q_pin, np.zeros(6), q_pin, mass, com, inertia, gravity, PIN_OMEGA)
    np.testing.assert_allclose(A[0] @ np.r_[q_pin, np.zeros(6)] + b[0], at_pin, atol=1e-12)
    assert np.allclose(at_pin[3:], -mass * gravity)  # At rest on its pin: exactly anti-gravity.
    for _ in range(5):  # Micrometre / microradian deviations (and velocities), as a frozen object sees.
        rotation = RollPitchYaw(*rng.normal(scale=1e-5, size=3)).ToQuaternion()
        q = np.r_[rotation.multiply(Quaternion(q_pin[:4])).wxyz(), q_pin[4:] + rng.normal(scale=1e-5, size=3)]
        v = rng.normal(scale=1e-3, size=6)
        exact = _exact_pin_force(q, v, q_pin, mass, com, inertia, gravity, PIN_OMEGA)
        linear = A[0] @ np.r_[q, v] + b[0]
        assert np.linalg.norm(linear - exact) <= 1e-4 * np.linalg.norm(exact - at_pin)


def test_a_resting_block_away_from_the_hand_freezes_again():
    """With sleeping enabled, an awake block that rests ``sleep_ticks`` steps away from the hand is frozen
    where it lies (and its count restarts); one dropped just under the palm, still falling, is not."""
    harness = MakeStationHarness(LoadScenario("grasp", scenario_text="{freeze: {enabled: true, sleep_ticks: 3}}"))
    objects = harness.objects
    objects.set_pose(harness.context, "block_4", RigidTransform([0.25, 0.19, 0.6005]))  # Resting in the box.
    palm = objects.hand_points(harness.context)[-1]
    objects.set_pose(harness.context, "block_5", RigidTransform(palm + [0, 0, -0.05]))  # Falls from the hand.
    index, near = objects.index("block_4"), objects.index("block_5")
    for _ in range(20):
        harness.step(1)
        if objects.frozen_mask(harness.context)[index]:
            break
    frozen = objects.frozen_mask(harness.context)
    assert frozen[index], "a resting block did not freeze"
    assert not frozen[near], "a falling block froze"
    assert objects.get_state(harness.context)["still_ticks"][index] == 0
    before = objects.positions(harness.context)[index].copy()
    harness.step(10)
    assert np.abs(objects.positions(harness.context)[index, 4:] - before[4:]).max() < 1e-4
