"""Retrieve (Building Blocks, between Search and Orient): take the target block out of the pile and set it down
alone on the staging area, in whatever pose it lies.

Not one of the paper's four sub-tasks as such: the paper's Search "digs and retrieves" the block, and Orient and
Grasp then act on a block clear of its neighbours. Here the retrieve is a stage of its own, so that Orient and
Grasp meet the states they are good at (inside the pile Orient stood up about 1 in 10 blocks, Grasp lifted 4 of 15
upright ones; on the staging area both succeed in about 0.9). It is *scripted*: the stage runs its base
(``tasks/scripted/block_retrieve_script.py``) alone, with no learned correction (``Task.scripted``), and ends when
the script is done (the block set down and the hand back up) or gives up.

Reset (as Search's): a cached settled pile, a target of a sampled training type, the easiest of its type to take
out first (``blocks_common.retrieve_order``), blocks far from it frozen, the open hand 3 cm over its
neighbourhood's top (plus ``hover_height``). Success: the block rests on the staging area (3 cm of slack, as the
script's), out of the hand's touch. Reward: minus the block's distance to the staging point (m), plus the shared
penalties; nothing trains on it.
"""

import numpy as np

from seqdex_drake.harness import ResolvePackageUrl
from seqdex_drake.modeling.blocks import BLOCK_SPECS
from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q
from seqdex_drake.scene.piles import LoadPiles
from seqdex_drake.tasks.base import ResetError, Task, TaskConfig
from seqdex_drake.tasks.blocks_common import STAGING_HIGH, STAGING_LOW, retrieve_order
from seqdex_drake.tasks.rewards import RewardWeights, penalties
from seqdex_drake.tasks.scripted.block_retrieve_script import TABLE_Z, block_extent, block_geometry, on_staging_area
from seqdex_drake.tasks.search import block_type_of

#: A block set down counts as resting on the table while its lowest point is within this of the table top (m).
RESTING_GAP = 0.01


def default_config() -> TaskConfig:
    """800 steps (13.3 s): the retrieve's three grip attempts take 300, the carry and set-down 200-300; a block
    dropped beside the box is gripped again in the rest."""
    return TaskConfig(name="retrieve", scenario="building_blocks/search", episode_length=800, ema=1.0,
                      hand_actions=False, residual="block_retrieve_script",
                      reward=RewardWeights(progress=1.0, fingertip=0.0, action=-0.001, torque=-0.003))


def block_staged(X_WB, block_type: int) -> bool:
    """Whether a block of ``block_type`` at pose ``X_WB`` (a RigidTransform) rests on the staging area, as the
    retrieve leaves it (3 cm of slack; its lowest point within ``RESTING_GAP`` of the table). The retrieve's
    success is this and the block out of the hand's touch."""
    centre, bottom = block_extent(X_WB.translation(), X_WB.rotation().matrix(),
                                  float(BLOCK_SPECS[block_type].footprint[0]))
    return bool(on_staging_area(centre) and bottom < TABLE_Z + RESTING_GAP)


def start_retrieve(env, q_pile: np.ndarray, block_type: int) -> str:
    """Restores pile ``q_pile`` (every block awake) in ``env``, targets the block of ``block_type`` easiest to take
    out (``retrieve_order``), freezes the blocks far from it and hovers the open hand 3 cm over the top of its
    neighbourhood (plus the config's ``hover_height``). Returns the target's name."""
    names = env.objects.names
    env.objects.set_positions(env.context, q_pile, frozen=np.zeros(len(names), dtype=bool))
    blocks = [k for k, name in enumerate(names) if name.startswith("block_")]
    rows = [k for k in blocks if block_type_of(names[k]) == block_type]
    if not rows:
        raise ResetError(f"the pile has no block of type {block_type}; choose one of "
                         f"{sorted({block_type_of(names[k]) for k in blocks})}")
    row = blocks[retrieve_order(q_pile[blocks], [blocks.index(k) for k in rows])[0]]
    env.objects.freeze_far_from(env.context, q_pile[row, 4:])
    env.set_target(names[row])
    near = np.linalg.norm(q_pile[:, 4:6] - q_pile[row, 4:6], axis=1) < 0.08
    env.set_robot(env.hover_arm(np.r_[q_pile[row, 4:6], np.max(q_pile[near, 6]) + 0.03]), ALLEGRO_OPEN_Q)
    return names[row]


class RetrieveTask(Task):
    """Take the target block out of the pile onto the staging area (scripted)."""

    scripted = True

    def reset(self, env, rng) -> None:
        piles = LoadPiles(ResolvePackageUrl(env.scenario.pile_file), env.objects.names)
        q = piles[int(rng.integers(len(piles)))]
        start_retrieve(env, q, int(rng.choice(env.config.object_types)))

    def _length(self, env) -> float:
        return float(BLOCK_SPECS[block_type_of(env.target_object)].footprint[0])

    def reward_terms(self, env, action):
        centre, _ = block_geometry(env.observation_values(), self._length(env))
        distance = float(np.linalg.norm(centre[:2] - (STAGING_LOW + STAGING_HIGH) / 2))
        return {"staging_distance": -self.config.reward.progress * distance,
                **penalties(self.config.reward, action, env.hand_torque())}

    def is_success(self, env) -> bool:
        return bool(block_staged(env.object_pose(), block_type_of(env.target_object))
                    and not env.objects.touches_robot(env.plant_context, env.target_object))
