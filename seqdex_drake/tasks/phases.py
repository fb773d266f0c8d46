"""Scripted phases of an episode, as the authors' release has them (``../shared/TRAINING.md``).

The release does not leave a whole episode to the policy. Its tool Grasp lets the policy move the wrist only for
the first 60 steps, lifts the wrist by script (+z) over steps 60-90, and then holds the arm and freezes the
fingers; its block Grasp lifts by script after step 75. A :class:`ScriptedPhases` config describes such a
schedule for any sub-task, and :func:`apply_phases` turns the policy's action into the applied one: the env
(:class:`~seqdex_drake.envs.subtask_env.SubtaskEnv`) calls it every step, and a deployed policy system runs the
same function on its own step counter, so training and the chain apply the same schedule.

What the schedule overrides is the *applied* action (what the previous-action observation shows); the learner
still stores its own sample. Off by default (every step the policy's): the paper's MDP, for users with a cluster.
"""

import dataclasses

#: Indices of the wrist translation in the 19-dim action (after the 16 hand joints).
WRIST = slice(16, 19)


@dataclasses.dataclass
class ScriptedPhases:
    """When the policy acts and when a script does, in policy steps from the episode's start (0-based)."""

    policy_wrist_steps: int = -1
    """The policy's wrist action applies in steps ``0 .. policy_wrist_steps - 1``; after that the wrist follows the
    script (the lift, else still). -1: the policy moves the wrist throughout."""
    lift_start: int = -1
    """First step of the scripted lift (-1: no lift)."""
    lift_end: int = -1
    """First step after the scripted lift."""
    lift_action: float = 1.0
    """Wrist z action during the lift, in [0, 1] (1: ``TaskConfig.wrist_step`` m per step upward)."""
    freeze_hand_step: int = -1
    """From this step on the hand holds its joint targets whatever the policy sends (-1: never)."""

    def __post_init__(self):
        if self.lift_start >= 0 and not self.lift_end > self.lift_start:
            raise ValueError(f"ScriptedPhases: lift_end ({self.lift_end}) must be after lift_start "
                             f"({self.lift_start})")
        if not 0.0 <= self.lift_action <= 1.0:
            raise ValueError(f"ScriptedPhases: lift_action must be in [0, 1], got {self.lift_action}")

    @property
    def enabled(self) -> bool:
        """Whether any phase overrides the policy."""
        return self.policy_wrist_steps >= 0 or self.lift_start >= 0 or self.freeze_hand_step >= 0

    def scripted_wrist(self, step: int) -> bool:
        """Whether the wrist action of ``step`` is the script's."""
        return (0 <= self.policy_wrist_steps <= step) or (0 <= self.lift_start <= step < self.lift_end)

    def hand_frozen(self, step: int) -> bool:
        """Whether the hand holds its targets at ``step``."""
        return 0 <= self.freeze_hand_step <= step


def apply_phases(phases: ScriptedPhases | None, step: int, action: list[float],
                 previous_action: list[float]) -> tuple[list[float], bool]:
    """The applied action of ``step`` (a new list) and whether the hand holds its targets.

    Args:
        phases: the schedule (None or disabled: the action unchanged).
        step: the policy step in the episode, 0 for the first.
        action: the policy's action after clipping (19 floats).
        previous_action: the action applied at the previous step (its hand part is kept while the hand is frozen).
    """
    if phases is None or not phases.enabled:
        return action, False
    applied = list(action)
    if phases.scripted_wrist(step):
        lifting = 0 <= phases.lift_start <= step < phases.lift_end
        applied[WRIST] = [0.0, 0.0, phases.lift_action if lifting else 0.0]
    frozen = phases.hand_frozen(step)
    if frozen:
        applied[:16] = previous_action[:16]
    return applied, frozen


def release_tool_grasp_phases() -> ScriptedPhases:
    """The release's tool Grasp schedule: the policy's wrist for 60 steps, a lift over steps 60-90 (0.15 m at
    0.005 m per step), then the arm still and the fingers frozen."""
    return ScriptedPhases(policy_wrist_steps=60, lift_start=60, lift_end=90, lift_action=1.0, freeze_hand_step=90)


def release_block_grasp_phases() -> ScriptedPhases:
    """The release's block Grasp schedule: the policy's wrist for 75 steps, then a scripted lift to the end of the
    150-step episode (at ``lift_action`` 1: 0.375 m at 0.005 m per step, so the 0.30 m of success is cleared
    from about step 135 even if the policy did not lift at all; a base that lifts earlier clears it sooner); the
    hand stays the policy's."""
    return ScriptedPhases(policy_wrist_steps=75, lift_start=75, lift_end=150, lift_action=1.0)
