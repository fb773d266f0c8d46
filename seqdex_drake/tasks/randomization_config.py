"""Which domain randomizations are on, and their ranges: :class:`RandomizationConfig` (the paper's table, appendix
"Domain randomization of all the sub-tasks"; what each group does in Drake terms: ``envs/randomization.py``)."""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass
class RandomizationConfig:
    """Which randomizations are on, and their ranges (defaults: the paper's table, every group off).

    The table's joint rows read "Scaling, loguniform, [0.0, 0.01]", which no sampler can draw (log 0). The
    release's config has the limits as additive Gaussian (mean 0, std 0.01) and stiffness / damping as
    log-uniform scalings on [0.75, 1.5] / [0.3, 3.0]. We take the limits as the release does and, for the
    paper's table, stiffness / damping as a relative perturbation of at most 1%: log-uniform on [0.99, 1.01].
    :meth:`release` gives the release's ranges.
    """

    robot_mass: bool = False
    """Scale the mass of each body of the ``robot_mass_instances``."""
    robot_mass_instances: list[str] = dataclasses.field(default_factory=lambda: ["allegro"])
    """Model instances whose bodies' masses are randomized. The release's robot has gravity disabled, so its mass
    randomization changes inertia only; here the Franka is held up by gravity compensation computed with nominal
    masses, so scaling its links becomes a compensation error (0.5x: the palm drifts ~13 cm/s). Hence the Allegro
    only by default; add ``"franka"`` to include the arm."""
    robot_mass_range: list[float] = dataclasses.field(default_factory=lambda: [0.5, 1.5])
    """Uniform range of the robot mass factor."""
    robot_friction: bool = False
    """Scale each robot body's Coulomb friction."""
    robot_friction_range: list[float] = dataclasses.field(default_factory=lambda: [0.7, 1.3])
    """Uniform range of the robot friction factor."""
    joint_limits: bool = False
    """Add noise to every robot joint's lower and upper position limit."""
    joint_limit_std: float = 0.01
    """Standard deviation (rad) of the additive Gaussian limit noise."""
    joint_stiffness: bool = False
    """Scale each actuator's PD stiffness kp."""
    joint_stiffness_range: list[float] = dataclasses.field(default_factory=lambda: [0.99, 1.01])
    """Log-uniform range of the kp factor."""
    joint_damping: bool = False
    """Scale each actuator's PD damping kd and its joint's viscous damping (one factor per joint)."""
    joint_damping_range: list[float] = dataclasses.field(default_factory=lambda: [0.99, 1.01])
    """Log-uniform range of the damping factor."""
    object_mass: bool = False
    """Scale each loose object's mass (while it is not frozen)."""
    object_mass_range: list[float] = dataclasses.field(default_factory=lambda: [0.5, 1.5])
    """Uniform range of the object mass factor."""
    object_friction: bool = False
    """Scale each loose object's Coulomb friction."""
    object_friction_range: list[float] = dataclasses.field(default_factory=lambda: [0.5, 1.5])
    """Uniform range of the object friction factor."""
    object_scale: bool = False
    """Scale each loose object's geometry uniformly (changed only at resets)."""
    object_scale_range: list[float] = dataclasses.field(default_factory=lambda: [0.95, 1.05])
    """Uniform range of the object scale."""
    object_pose_noise: bool = False
    """Perturb the target object's pose at each task reset (skipped when it lies in a pile, see below)."""
    object_position_std: float = 0.02
    """Standard deviation (m) of the additive position noise, per axis."""
    object_rotation_std: float = 0.2
    """Standard deviation (rad) of each component of the rotation-vector noise, about the centre of mass."""
    isolation_radius: float = 0.08
    """Pose noise is skipped when another object's origin lies this close (m) to the target's: moving one block
    of a settled pile would interpenetrate its neighbours (the pile is already a random arrangement)."""
    observation_noise: bool = False
    """Additive Gaussian noise on every observation entry."""
    observation_correlated_std: float = 0.001
    """Std of the correlated part, drawn once per episode."""
    observation_uncorrelated_std: float = 0.002
    """Std of the uncorrelated part, drawn every step."""
    action_noise: bool = False
    """Additive Gaussian noise on the action before it is clipped and used."""
    action_correlated_std: float = 0.015
    """Std of the correlated part, drawn once per episode."""
    action_uncorrelated_std: float = 0.05
    """Std of the uncorrelated part, drawn every step."""
    gravity: bool = False
    """Additive Gaussian noise on each gravity component."""
    gravity_std: float = 0.4
    """Std (m/s^2) of the gravity noise per axis."""
    resample_every_sim_steps: int = 1000
    """Physical parameters are re-drawn after this many plant steps (paper: every 1000 simulation steps)."""

    GROUPS = ("robot_mass", "robot_friction", "joint_limits", "joint_stiffness", "joint_damping", "object_mass",
              "object_friction", "object_scale", "object_pose_noise", "observation_noise", "action_noise", "gravity")

    def any_enabled(self) -> bool:
        return any(getattr(self, group) for group in self.GROUPS)

    @classmethod
    def paper(cls) -> RandomizationConfig:
        """The paper's table with every group on (training configuration)."""
        return cls(**{group: True for group in cls.GROUPS})

    @classmethod
    def release(cls) -> RandomizationConfig:
        """The release's ``randomization_params``: its kp / kd ranges, object friction [0.7, 1.3], no pose noise."""
        return dataclasses.replace(cls.paper(), joint_stiffness_range=[0.75, 1.5], joint_damping_range=[0.3, 3.0],
                                   object_friction_range=[0.7, 1.3], object_pose_noise=False)
