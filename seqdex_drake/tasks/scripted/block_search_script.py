"""A scripted base for the Building Blocks ``search`` sub-task (make the target block visible to the top-down
camera), acting only through the env's 19-dim action space; the base of the budget variant's residual policy
(``tasks/search.py`` ``budget_config``, ``tasks/residual.py``).

Why moving the hand away is most of the task: the pile (72 blocks in a 0.60 x 0.416 m box) is about two layers
deep, and the reset puts the open hand right over the target, its hand centre (``p_PalmHc_Palm``) 8 cm above the
highest block origin within 8 cm. The label camera looks straight down from (0.25, 0.19, 1.35) (128 x 128, focal
length 154.5 px: about 4.3 mm per pixel at the pile) and the count is of the target's label in the rendered image,
so whatever lies between them occludes it: the hand's flat fingers (tips at the hand centre + (0.134, +-0.044,
0.04), the thumb's at + (0.049, 0.076, 0.018)) cover the target's middle. Over the resets of seeds 0-39 of the
default config, 28 / 40 targets are above their threshold at reset; with the same hand placed high and 0.4 m
behind (so that it hides nothing) 38 / 40 are: the other 2 (seeds 16 and 26, 4 and 3 pixels) lie under other
blocks.

Strategy: take the open hand sideways off the camera's line of sight to the target and hold it there, above the
walls. The action is a function of the observation only (:meth:`ScriptedBlockSearch.act`; ``step`` is unused),
so it is Markov in (observation, step) and a residual policy's correction at any step leaves the script's next
action well defined.

* Hand: the open hand of the reset (the hand-target EMA, 0.6, then never lags the script). Flat fingers are the
  narrowest shape seen from above across y, and the hand touches nothing, so the pile and the target stay put.
* Wrist: ``clip((gain * (goal - hand) - damping * palm displacement per step) / 0.005)`` on the observed hand
  centre, gain 0.4, damping 1 (as ``tasks/scripted/block_grasp_script.py``). The goal is level with the target in x,
  beside it in y, toward the box's middle (targets at y <= 0.19 m go to +y, the thumb's side, by ``thumb_side``
  = 0.14 m; the others to -y by ``ring_side`` = 0.17 m, the thumb trailing): the hand's near edge (the ring
  finger's side, 5.7 cm from the hand centre, or the thumb's, 8.8 cm) then clears a 1x4 block lying across y
  (6 cm half-length) with 2 cm to spare, more than the perspective shift of the raised hand's edge toward the
  target (the camera's rays spread from its axis at y = 0.19 m; at most about 1 cm in the box). Its height is
  at least 4.5 cm above the wall tops (0.765 m) and 16 cm above the target: the open hand's lowest point (the
  thumb) is about at the hand centre's height, and a goal near a side wall puts the fingers over it. The hand
  gets there in about 30 steps (0.14-0.17 m at 5 mm per step) and holds until the last step, where success is
  tested.

Measured in the budget env with the residual at zero (``seqdex rollout --task search --zero-action --episodes
100 --seed S --out results/building_blocks/search_script_seed{S}.json``):
95 / 100 on seed 0, 98 / 100 on seed 1000, 94 / 100 on seed 2000 (287 / 300); no termination or simulator
error. Every failure is a buried target (4 pixels or fewer at reset with the hand gone: seeds 16, 26, 60, 73,
87, 1035, 1036, 2013, 2041, 2051, 2058, 2059, 2088), so the script reaches what moving the hand away can give.
The command with ``--episodes 20 --seed 0``: 19 / 20 (seed 16 fails). The same script acting in the default env
(its actions sent as they are, :func:`run_episode` with ``make_env("search")``): 38 / 40 on seeds 0-39 (16 and
26 fail). The paper variant's zero action (``seqdex rollout --task search --zero-action --preset paper
--episodes 20 --seed 0``), which curls the fingers to their mid-range over the target and holds the wrist:
12 / 20; with ``--episodes 100 --seed S --out results/building_blocks/search_zero_paper_seed{S}.json``,
54 / 100 on seed 0, 55 / 100 on seed 1000 and 55 / 100 on seed 2000 (164 / 300).

Failure causes seen: only buried targets (a few pixels even with the hand gone; the targets' origins at
z 0.60-0.63 m, the lowest layer, under other blocks). The script does not dig: a hand that can only
translate, palm down, rakes with three finger strips along x and disturbs the pile (the blocks a dig moves may
bury the target again or push it where Orient cannot reach it), for at most the few percent of buried targets;
that is left to the residual policy, which may move the fingers and the wrist. The target moves by under 1.4 cm
(seeds 0-39) and the pile stays in the box: over 75 steps on seeds 1, 3, 5, 11, 20 and 33 the blocks moved as
much under the script as under a still open hand (the pile relaxes a little at the Search scene's 1/240 s plant
step: at most 1-2 cm, one block sliding 6-10 cm on seed 5 either way), so Orient and Grasp find the target where
the reset put it.
"""

from __future__ import annotations

import numpy as np

from seqdex_drake.observation_layout import rotation_matrix
from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q, p_PalmHc_Palm, unscale_limits_to_action
from seqdex_drake.scene.piles import BOX_CENTER, BOX_WALL_HEIGHT
from seqdex_drake.tasks.scripted.scripted_episode import play_script

WRIST_STEP = 0.005
"""Metres per step of the hand centre at wrist action 1 (the env's ``wrist_step``)."""
CONTROL_RATE = 60.0
"""Policy steps per second (the env's control period is 1/60 s)."""

OPEN_ACTION = unscale_limits_to_action(ALLEGRO_OPEN_Q)
"""The hand's action for the open hand (the reset's hand), flat fingers along world +x."""


class ScriptedBlockSearch:
    """The scripted search (see the module docstring): :meth:`act` of the observation only (``step`` is taken
    for the base-controller interface and unused; there is no state to reset).

    Args:
        thumb_side: lateral offset of the hand centre from the target [m] when moving toward the thumb (+y).
        ring_side: the same when moving toward the ring finger (-y): the open thumb sticks out 9 cm to +y, so
            the hand must go further that way.
        split_y: targets with world y at most this go to +y, the others to -y (toward the box's middle, away
            from the near side wall) [m].
        clear_height: the hand centre's least goal height above the box's wall top [m] (the open hand's lowest
            point, the thumb, is about at the hand centre's height).
        target_rise: the hand centre's least goal height above the target's origin [m].
        gain, damping: the wrist law's proportional gain and velocity damping (as
        ``tasks/scripted/block_grasp_script``).
        wrist_step: the env's ``wrist_step`` [m per step at action 1].
    """

    def __init__(self, thumb_side=0.14, ring_side=0.17, split_y=float(BOX_CENTER[1]), clear_height=0.045,
                 target_rise=0.16, gain=0.4, damping=1.0, wrist_step=WRIST_STEP):
        self.thumb_side, self.ring_side, self.split_y = thumb_side, ring_side, split_y
        self.clear_height, self.target_rise = clear_height, target_rise
        self.gain, self.damping, self.wrist_step = gain, damping, wrist_step

    def reset(self, env) -> None:
        pass

    def goal_and_hand(self, observation) -> tuple[np.ndarray, np.ndarray]:
        """The hand-centre goal (beside the target, off the camera's line of sight, above the walls) and the
        observed hand centre, world [m]."""
        o = observation
        p_target = np.asarray(o[111:114], float)
        side = self.thumb_side if p_target[1] <= self.split_y else -self.ring_side
        height = max(BOX_CENTER[2] + BOX_WALL_HEIGHT + self.clear_height, p_target[2] + self.target_rise)
        goal = np.array([p_target[0], p_target[1] + side, height])
        return goal, np.asarray(o[98:101], float) + rotation_matrix(o[101:105]) @ p_PalmHc_Palm

    def act(self, observation, step: int) -> np.ndarray:
        """The action for ``observation`` (the env's, 160 or 161 entries) at ``step``."""
        o = np.asarray(observation, dtype=float)
        goal, hand = self.goal_and_hand(o)
        velocity = np.asarray(o[105:108], float) / CONTROL_RATE  # Palm displacement per step.
        wrist = np.clip((self.gain * (goal - hand) - self.damping * velocity) / self.wrist_step, -1.0, 1.0)
        return np.clip(np.r_[OPEN_ACTION, wrist], -1.0, 1.0)

    def action(self, env, step: int) -> np.ndarray:
        return self.act(env.observation(), step)


def run_episode(env, seed: int, controller: ScriptedBlockSearch | None = None) -> dict:
    """One episode of the scripted search from ``env.reset(seed=seed)``: in an env with a residual base (the
    budget env) zero corrections, otherwise ``controller``'s actions (default :class:`ScriptedBlockSearch`).
    Returns the env's ``success`` at the last step, the target's pixel count at reset and at the end, and how far
    the target moved [m]."""
    info, first, observation = play_script(env, seed, controller or ScriptedBlockSearch())
    start_pixels, start = float(first[159]), np.array(first[111:114], float)
    return {"success": bool(info["success"]), "start_pixels": start_pixels, "pixels": float(observation[159]),
            "target_moved": float(np.linalg.norm(np.array(observation[111:114], float) - start))}
