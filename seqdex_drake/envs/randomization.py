"""Domain randomization: the paper's table (appendix, "Domain randomization of all the sub-tasks") in Drake.

Every draw comes from a ``pydrake.common.RandomGenerator`` through ``pydrake.common.schema`` distributions;
the environment hands :meth:`DomainRandomizer.on_reset` its gymnasium ``np_random``, from which one seed is
drawn after the task's reset, so the env seed drives everything. What each item does in Drake terms:

=================  ===========================================================================================
robot/object mass  ``RigidBody.SetMass(plant_context, m)`` (a context parameter), per body. Frozen objects keep
                   the freezer's mass (nominal x ``freeze.mass_scale``): its pin and anti-gravity forces assume
                   it. ``SceneObjects.set_frozen`` writes nominal masses; :meth:`DomainRandomizer.on_step`
                   (after ``SceneObjects.update``) and :meth:`~DomainRandomizer.on_reset` write them back.
friction           ``SceneGraph.AssignRole(sg_context, ..., RoleAssign.kReplace)`` with the nominal proximity
                   properties and a scaled ``CoulombFriction`` (static and dynamic), one factor per body.
object scale       ``SceneGraph.ChangeShape(sg_context, ...)`` on every geometry of the object (collision,
                   illustration, perception: the label camera sees it), poses scaled about the body origin; the
                   centre of mass scales by s and the unit inertia by s^2 (``SetSpatialInertiaInBodyFrame``);
                   the mass is the mass item's. ChangeShape drops the context's collision filters of the geometry,
                   so the freezer's filters are re-declared (``SceneObjects.redeclare_filters``).
PD stiffness and   ``JointActuator.set_controller_gains(PdControllerGains)`` (kp, kd) and
damping            ``Joint.SetDampingVector(plant_context, ...)`` (viscous damping, same factor as kd).
joint limits       ``Joint.set_position_limits``.
gravity            ``plant.mutable_gravity_field().set_gravity_vector``. The Franka's gravity compensation
                   (InverseDynamics on this plant) sees it, but with nominal masses (its own default context).
pose noise         the target's pose after ``Task.reset`` (position, rotation vector about the centre of mass),
                   lifted out of the floor; skipped in a pile or in hand (``DomainRandomizer.apply_pose_noise``).
                   Tasks record their start state (Orient's start rotation) before it: the resting pose.
obs/action noise   additive Gaussian: correlated (drawn per episode) + uncorrelated (per step).
=================  ===========================================================================================

PD gains, joint limits and gravity are model data, not context parameters, in Drake 1.51 (the gains are a
``JointActuator`` member read by the discrete solver each step; pydrake binds no context overload). Each
SubtaskEnv builds its own plant, so they are still per environment, and take effect from the next step.
(A plant shared by several contexts would share them.)

Physical parameters are re-drawn when ``resample_every_sim_steps`` plant steps (2 ms) have passed: mid-episode
all but the object scale (a geometry jump in contact would be an impulse); the scale at the next reset.
Isaac Gym counts ``gym.simulate`` calls (one 1/60 s policy step there): 1000 of them are about 8300 plant
steps here; set the field accordingly to match the release's wall-clock period.

The configuration, :class:`RandomizationConfig`, lives in ``tasks/randomization_config.py`` (importable from
here too).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.common import RandomGenerator
from pydrake.common.eigen_geometry import AngleAxis
from pydrake.common.schema import GaussianVectorX, UniformVectorX
from pydrake.geometry import Box, Capsule, Convex, Cylinder, Ellipsoid, Mesh, ProximityProperties, RoleAssign, Sphere
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.plant import CoulombFriction
from pydrake.multibody.tree import PdControllerGains, SpatialInertia, UnitInertia

from seqdex_drake.tasks.randomization_config import RandomizationConfig


@dataclasses.dataclass
class PhysicalSample:
    """One draw of the physical parameters (factors and offsets; None for a disabled group)."""

    robot_mass: np.ndarray | None
    robot_friction: np.ndarray | None
    lower_offset: np.ndarray | None
    upper_offset: np.ndarray | None
    kp_scale: np.ndarray | None
    damping_scale: np.ndarray | None
    object_mass: np.ndarray | None
    object_friction: np.ndarray | None
    object_scale: np.ndarray | None
    gravity_offset: np.ndarray | None


def _uniform(generator: RandomGenerator, bounds, n: int) -> np.ndarray:
    return np.asarray(UniformVectorX(min=np.full(n, bounds[0]), max=np.full(n, bounds[1])).Sample(generator))


def _gaussian(generator: RandomGenerator, std: float, n: int) -> np.ndarray:
    return np.asarray(GaussianVectorX(mean=np.zeros(n), stddev=np.full(n, std)).Sample(generator))


def _loguniform(generator: RandomGenerator, bounds, n: int) -> np.ndarray:
    return np.exp(_uniform(generator, np.log(bounds), n))


def _scaled_shape(shape, s: float):
    """``shape`` uniformly scaled by ``s`` about its frame's origin."""
    if isinstance(shape, Convex | Mesh):
        return type(shape)(shape.source(), shape.scale3() * s)
    if isinstance(shape, Box):
        return Box(shape.size() * s)
    if isinstance(shape, Sphere):
        return Sphere(shape.radius() * s)
    if isinstance(shape, Cylinder | Capsule):
        return type(shape)(shape.radius() * s, shape.length() * s)
    if isinstance(shape, Ellipsoid):
        return Ellipsoid(shape.a() * s, shape.b() * s, shape.c() * s)
    raise ValueError(f"object scale randomization cannot scale a {type(shape).__name__}")


class DomainRandomizer:
    """Applies a :class:`RandomizationConfig` to one :class:`~seqdex_drake.envs.subtask_env.SubtaskEnv`."""

    def __init__(self, env, config: RandomizationConfig):
        self.env, self.config = env, config
        self.enabled = config.any_enabled()
        plant, self.scene_graph = env.plant, env.objects.scene_graph
        self.plant, self.source_id = plant, plant.get_source_id()
        robot = [env.arm, env.hand]
        self.robot_bodies = [plant.get_body(i) for m in robot for i in plant.GetBodyIndices(m)]
        self.actuators = [plant.get_joint_actuator(i) for m in robot for i in plant.GetJointActuatorIndices(m)]
        self.joints = [a.joint() for a in self.actuators]
        self.nominal_gains = [(a.get_controller_gains().p, a.get_controller_gains().d) for a in self.actuators]
        self.nominal_damping = [j.default_damping_vector() for j in self.joints]
        self.nominal_limits = [(j.position_lower_limits(), j.position_upper_limits()) for j in self.joints]
        self.nominal_gravity = np.array(plant.gravity_field().gravity_vector())
        mass_instances = [plant.GetModelInstanceByName(name) for name in config.robot_mass_instances]
        self.robot_mass_bodies = [b for b in self.robot_bodies if b.model_instance() in mass_instances]
        self.robot_mass0 = np.array([b.default_mass() for b in self.robot_mass_bodies])
        self.object_mass0 = np.array([b.default_mass() for b in env.objects.bodies])
        inspector = self.scene_graph.model_inspector()
        self.robot_geometries = [plant.GetCollisionGeometriesForBody(b) for b in self.robot_bodies]
        self.robot_geometry_set = {g for gs in self.robot_geometries for g in gs}
        self.object_geometries = [plant.GetCollisionGeometriesForBody(b) for b in env.objects.bodies]
        self.nominal_proximity = {g: ProximityProperties(inspector.GetProximityProperties(g))
                                  for gs in self.robot_geometries + self.object_geometries for g in gs}
        self.object_all_geometries = [inspector.GetGeometries(plant.GetBodyFrameIdOrThrow(b.index()))
                                      for b in env.objects.bodies]
        self.object_mass_factor = np.ones(len(env.objects.bodies))
        self.sample: PhysicalSample | None = None
        self._physical: RandomGenerator | None = None
        self._episode = RandomGenerator(0)
        self._steps_since_resample, self._last_time, self._scale_due = 0, 0.0, True
        self._obs_corr = self._act_corr = 0.0

    # --------------------------------------------------------------------------------------- sampling
    def sample_physical(self, generator: RandomGenerator) -> PhysicalSample:
        """Draws every enabled physical parameter (disabled groups: None)."""
        c, na, no = self.config, len(self.actuators), len(self.env.objects.bodies)
        nm, nr = len(self.robot_mass_bodies), len(self.robot_bodies)

        def draw(group, sampler, *args):
            return sampler(generator, *args) if getattr(c, group) else None

        return PhysicalSample(
            robot_mass=draw("robot_mass", _uniform, c.robot_mass_range, nm),
            robot_friction=draw("robot_friction", _uniform, c.robot_friction_range, nr),
            lower_offset=draw("joint_limits", _gaussian, c.joint_limit_std, na),
            upper_offset=draw("joint_limits", _gaussian, c.joint_limit_std, na),
            kp_scale=draw("joint_stiffness", _loguniform, c.joint_stiffness_range, na),
            damping_scale=draw("joint_damping", _loguniform, c.joint_damping_range, na),
            object_mass=draw("object_mass", _uniform, c.object_mass_range, no),
            object_friction=draw("object_friction", _uniform, c.object_friction_range, no),
            object_scale=draw("object_scale", _uniform, c.object_scale_range, no),
            gravity_offset=draw("gravity", _gaussian, c.gravity_std, 3))

    def nominal_sample(self) -> PhysicalSample:
        """The identity draw of every enabled group (factors 1, offsets 0; disabled groups: None)."""
        c, na, no = self.config, len(self.actuators), len(self.env.objects.bodies)
        nm, nr = len(self.robot_mass_bodies), len(self.robot_bodies)

        def value(group, fill, n):
            return np.full(n, fill) if getattr(c, group) else None

        return PhysicalSample(
            robot_mass=value("robot_mass", 1.0, nm), robot_friction=value("robot_friction", 1.0, nr),
            lower_offset=value("joint_limits", 0.0, na), upper_offset=value("joint_limits", 0.0, na),
            kp_scale=value("joint_stiffness", 1.0, na), damping_scale=value("joint_damping", 1.0, na),
            object_mass=value("object_mass", 1.0, no), object_friction=value("object_friction", 1.0, no),
            object_scale=value("object_scale", 1.0, no), gravity_offset=value("gravity", 0.0, 3))

    # -------------------------------------------------------------------------------------- applying
    def apply_physical(self, sample: PhysicalSample, include_scale: bool = True) -> None:
        """Writes a sample into the env's contexts (and, for limits and gravity, its plant)."""
        self.sample = sample
        root, plant = self.env.context, self.plant
        plant_context = plant.GetMyMutableContextFromRoot(root)
        sg_context = self.scene_graph.GetMyMutableContextFromRoot(root)
        if include_scale and sample.object_scale is not None:
            self._apply_scale(root, plant_context, sg_context, sample.object_scale)
        if sample.robot_mass is not None:
            for body, m0, f in zip(self.robot_mass_bodies, self.robot_mass0, sample.robot_mass, strict=True):
                body.SetMass(plant_context, m0 * f)
        if sample.object_mass is not None:
            self.object_mass_factor = sample.object_mass
        for geometries, factors in ((self.robot_geometries, sample.robot_friction),
                                    (self.object_geometries, sample.object_friction)):
            for body_geometries, f in zip(geometries, [] if factors is None else factors, strict=factors is not None):
                for g in body_geometries:
                    self.scene_graph.AssignRole(sg_context, self.source_id, g, self._friction(g, f),
                                                RoleAssign.kReplace)
        for k, (actuator, joint) in enumerate(zip(self.actuators, self.joints, strict=True)):
            kp, kd = self.nominal_gains[k]
            if sample.kp_scale is not None or sample.damping_scale is not None:
                kp_f = 1.0 if sample.kp_scale is None else sample.kp_scale[k]
                kd_f = 1.0 if sample.damping_scale is None else sample.damping_scale[k]
                actuator.set_controller_gains(PdControllerGains(p=kp * kp_f, d=kd * kd_f))
            if sample.damping_scale is not None:
                joint.SetDampingVector(plant_context, self.nominal_damping[k] * sample.damping_scale[k])
            if sample.lower_offset is not None:
                lower, upper = self.nominal_limits[k]
                lower, upper = lower + sample.lower_offset[k], upper + sample.upper_offset[k]
                joint.set_position_limits(np.minimum(lower, upper), np.maximum(lower, upper))
        if sample.gravity_offset is not None:
            plant.mutable_gravity_field().set_gravity_vector(self.nominal_gravity + sample.gravity_offset)
        self.sync_masses()

    def _friction(self, geometry, factor: float) -> ProximityProperties:
        props = ProximityProperties(self.nominal_proximity[geometry])
        if props.HasProperty("material", "coulomb_friction"):
            mu = props.GetProperty("material", "coulomb_friction")
            props.UpdateProperty("material", "coulomb_friction",
                                 CoulombFriction(mu.static_friction() * factor, mu.dynamic_friction() * factor))
        return props

    def _apply_scale(self, root, plant_context, sg_context, scales: np.ndarray) -> None:
        inspector = self.scene_graph.model_inspector()
        objects = self.env.objects
        state = objects.get_state(root)
        for body, geometries, s in zip(objects.bodies, self.object_all_geometries, scales, strict=True):
            for g in geometries:
                X = inspector.GetPoseInFrame(g)
                self.scene_graph.ChangeShape(sg_context, self.source_id, g, _scaled_shape(inspector.GetShape(g), s),
                                             RigidTransform(X.rotation(), X.translation() * s))
            M0 = body.default_spatial_inertia()
            G0 = M0.get_unit_inertia()
            G = UnitInertia(*(G0.get_moments() * s**2), *(G0.get_products() * s**2))
            body.SetSpatialInertiaInBodyFrame(plant_context, SpatialInertia(M0.get_mass(), M0.get_com() * s, G))
        objects.set_state(root, state)
        objects.redeclare_filters(root)  # ChangeShape dropped the geometries' freeze filters: declare them again.

    def sync_masses(self) -> None:
        """Writes the randomized masses back where ``SceneObjects.set_frozen`` restored nominal ones."""
        if not (self.config.object_mass or self.config.object_scale):
            return
        plant_context = self.plant.GetMyMutableContextFromRoot(self.env.context)
        frozen = self.env.objects.frozen_mask(self.env.context)
        scale = self.env.scenario.freeze.mass_scale
        for body, m0, f, is_frozen in zip(self.env.objects.bodies, self.object_mass0, self.object_mass_factor,
                                          frozen, strict=True):
            mass = m0 * (scale if is_frozen else f)
            if body.get_mass(plant_context) != mass:
                body.SetMass(plant_context, mass)

    def apply_pose_noise(self, generator: RandomGenerator, attempts: int = 5) -> bool:
        """Perturbs the target object's pose about its centre of mass, then lifts it out of any penetration.

        Skipped (returns False) when the target lies in a pile (another object within ``isolation_radius``) or
        touches the robot (held in hand): moving it would interpenetrate its neighbours or break the grasp. A
        draw that ends inside the robot (the open hand hovers just above) is re-drawn, ``attempts`` times at most.
        """
        env, c = self.env, self.config
        index = env.objects.index(env.target_object)
        p_WO = env.objects.positions(env.context)[:, 4:]
        if np.any(np.delete(np.linalg.norm(p_WO - p_WO[index], axis=1), index) < c.isolation_radius) or \
                self._penetration(index)[1]:
            return False
        X_WB = env.object_pose()
        p_BCm = env.object_body().CalcCenterOfMassInBodyFrame(env.plant_context)
        for _ in range(attempts):
            rotation_vector = _gaussian(generator, c.object_rotation_std, 3)
            angle = np.linalg.norm(rotation_vector)
            R = (RotationMatrix() if angle == 0 else RotationMatrix(AngleAxis(angle, rotation_vector / angle))) \
                @ X_WB.rotation()
            p_WCm = X_WB @ p_BCm + _gaussian(generator, c.object_position_std, 3)
            env.objects.set_pose(env.context, env.target_object, RigidTransform(R, p_WCm - R @ p_BCm))
            for _ in range(20):  # Lift out of the floor / table / walls.
                depth, touches_robot = self._penetration(index)
                if depth <= 0.0:
                    break
                X = env.object_pose()
                env.objects.set_pose(env.context, env.target_object,
                                     RigidTransform(X.rotation(), X.translation() + [0, 0, depth + 1e-4]))
            if depth <= 0.0 and not touches_robot:
                return True
        env.objects.set_pose(env.context, env.target_object, X_WB)
        return False

    def _penetration(self, index: int) -> tuple[float, bool]:
        """Deepest penetration of object ``index`` into anything but the robot, and whether it touches the robot."""
        mine = set(self.object_geometries[index])
        query = self.scene_graph.get_query_output_port().Eval(self.scene_graph.GetMyContextFromRoot(self.env.context))
        depth, robot = 0.0, False
        for pair in query.ComputePointPairPenetration():
            if (pair.id_A in mine) == (pair.id_B in mine):
                continue
            if pair.id_A in self.robot_geometry_set or pair.id_B in self.robot_geometry_set:
                robot = True
            else:
                depth = max(depth, pair.depth)
        return depth, robot

    def restore_nominal(self) -> None:
        """Puts the nominal model back (the :meth:`nominal_sample`), as a new environment has it, and forgets the
        draw: the next :meth:`on_reset` draws afresh. A no-op while nothing was drawn.

        ``SubtaskEnv.reset`` calls it on a seeded reset before the task's reset, which may simulate (Insert's
        scripted pickup, a tool settling): the episode then depends on its seed alone, not on the parameters an
        earlier episode drew."""
        if self.sample is None:
            return
        self.apply_physical(self.nominal_sample(), include_scale=True)
        self.sample, self._physical = None, None
        self.object_mass_factor = np.ones(len(self.env.objects.bodies))
        self._steps_since_resample, self._scale_due = 0, True

    # ------------------------------------------------------------------------------------ env hooks
    def on_reset(self, np_random: np.random.Generator, reseed: bool, task_reset: bool) -> None:
        """Called by ``SubtaskEnv.reset`` after the task reset (or state restore), before ``Initialize``.

        Draws this episode's seed from ``np_random``; re-draws the physical parameters on the first reset, on a
        seeded reset (``reseed``), or when a resample is due; draws the correlated noise; perturbs the target's
        pose when ``task_reset`` (not when restoring a saved state).
        """
        self._last_time = self.env.context.get_time()
        if not self.enabled:
            return
        seed = int(np_random.integers(2**32 - 1))
        if self._physical is None or reseed or self._scale_due or \
                self._steps_since_resample >= self.config.resample_every_sim_steps:
            self._physical = RandomGenerator(seed)
            self.apply_physical(self.sample_physical(self._physical), include_scale=True)
            self._steps_since_resample, self._scale_due = 0, False
        self._episode = RandomGenerator((seed + 1) % 2**32)
        c, n_obs = self.config, self.env.observation_space.shape[0]
        self._obs_corr = _gaussian(self._episode, c.observation_correlated_std, n_obs) if c.observation_noise else 0.0
        self._act_corr = _gaussian(self._episode, c.action_correlated_std, len(self.env.action_space.low)) \
            if c.action_noise else 0.0
        if task_reset and c.object_pose_noise and self.env.target_object:
            self.apply_pose_noise(self._episode)
        self.sync_masses()

    def on_step(self) -> None:
        """Called by ``SubtaskEnv.step`` after each control period's ``AdvanceTo`` and ``SceneObjects.update``."""
        if not self.enabled:
            return
        h = self.plant.time_step()
        time = self.env.context.get_time()
        self.maybe_resample(int(np.floor(time / h + 1e-6)) - int(np.floor(self._last_time / h + 1e-6)))
        self._last_time = time
        self.sync_masses()

    def maybe_resample(self, sim_steps: int) -> bool:
        """Counts ``sim_steps`` plant steps; re-draws the physical parameters (all but the object scale, which
        waits for the next reset) once ``resample_every_sim_steps`` have passed. Returns whether it did."""
        self._steps_since_resample += sim_steps
        if not self.enabled or self._steps_since_resample < self.config.resample_every_sim_steps:
            return False
        if self._physical is None:
            raise RuntimeError("reset the environment before stepping it")
        self.apply_physical(self.sample_physical(self._physical), include_scale=False)
        self._steps_since_resample, self._scale_due = 0, self.config.object_scale
        return True

    def perturb_observation(self, observation: np.ndarray) -> np.ndarray:
        """The observation plus the episode's correlated and a fresh uncorrelated noise (if enabled)."""
        if not self.config.observation_noise:
            return observation
        noise = self._obs_corr + _gaussian(self._episode, self.config.observation_uncorrelated_std, observation.size)
        return (observation + noise).astype(observation.dtype)

    def perturb_action(self, action: list[float]) -> list[float]:
        """The action (a list of floats, as ``SubtaskEnv.step`` handles it) plus the episode's correlated and a
        fresh uncorrelated noise (if enabled)."""
        if not self.config.action_noise:
            return action
        noise = _gaussian(self._episode, self.config.action_uncorrelated_std, len(action))
        return (np.asarray(action, dtype=float) + self._act_corr + noise).tolist()
