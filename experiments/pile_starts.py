"""Orient's starts inside the pile, as the whole chain meets them, and Orient's success there by the pick's keys.

Writes a Search -> Orient hand-off buffer (the ``seqdex collect`` format): per cached pile of the Search scene
(the piles Search trained on; the whole chain is evaluated on held-out ones), every block of the given types whose
centre lies where the hovering hand fits, the rest of the pile as cached, the open hand hovering over the block as
Orient's resets place it. ``seqdex rollout --scene building_blocks/search`` then runs Orient from each, and
``--table`` joins its episodes with the keys the chain's pick order sorts by
(``tasks/blocks_common.accessibility_order``: on the floor, upright, covered, at most a quarter roll from upright,
room for the roll, along the jaws; and on a long side, 70-110 deg):

    python experiments/pile_starts.py --out runs/handoffs/orient_pile_starts.npz
    seqdex rollout --task orient --zero-action --initial-states runs/handoffs/orient_pile_starts.npz \\
        --scene building_blocks/search --episodes 105 --seed 0 --out results/building_blocks/orient_pile_starts.json
    python experiments/pile_starts.py --out runs/handoffs/orient_pile_starts.npz \\
        --table results/building_blocks/orient_pile_starts.json

(``--episodes`` = the number of starts written; episode seed s starts from entry s mod N.) The keys of each start
are saved beside the buffer (``<out>.keys.json``).
"""

import argparse
import collections
import json
import sys
from pathlib import Path

import numpy as np

#: The keys ``--table`` breaks Orient's success down by.
KEYS = ("upright", "covered", "side", "quarter", "roll_blocked", "along_jaws", "on_floor")


def start_keys(q_blocks: np.ndarray, i: int) -> dict:
    """The pick order's keys of block row ``i`` of ``q_blocks`` (an (N, 7) [wxyz, xyz] pile of blocks)."""
    from seqdex_drake.tasks.blocks_common import QUARTER_ROLL, pick_keys

    keys = pick_keys(q_blocks, i)
    tilt = keys["tilt"]
    return {"tilt": round(tilt, 1), "upright": tilt < 20.0, "side": 70.0 <= tilt <= 110.0,
            "quarter": tilt <= QUARTER_ROLL, "covered": keys["covered"],
            "roll_blocked": keys["roll_blocked"], "along_jaws": keys["along_jaws"],
            "on_floor": keys["on_floor"]}


def write_starts(out: Path, types: list[int], limit: int | None) -> int:
    """Writes the buffer and its keys; returns the number of starts."""
    import dataclasses

    from seqdex_drake.chaining.terminal_buffer import HISTORY, TerminalBuffer
    from seqdex_drake.envs.subtask_env import make_env
    from seqdex_drake.harness import ResolvePackageUrl
    from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q
    from seqdex_drake.scene.piles import LoadPiles
    from seqdex_drake.tasks.blocks_common import reachable_region
    from seqdex_drake.tasks.registry import budget_config
    from seqdex_drake.tasks.run_config import observation_spec

    search = make_env("search", budget_config("search"))
    orient = make_env("orient", dataclasses.replace(budget_config("orient"), scenario=search.config.scenario))
    observation, _ = search.reset(seed=0)
    names = search.objects.names
    blocks = [k for k, name in enumerate(names) if name.startswith("block_")]
    piles = LoadPiles(ResolvePackageUrl(search.scenario.pile_file), names)
    buffer = TerminalBuffer("search", "orient", search.config.scenario,
                            observation_spec("search", observation.shape[0]), HISTORY)
    low, high = reachable_region()
    keys = []
    for number, q in enumerate(piles):
        for k in blocks:
            block_type = int(names[k].split("_")[1])
            p = q[k, 4:]
            if block_type not in types or not (np.all(p[:2] >= low) and np.all(p[:2] <= high)):
                continue
            search.objects.set_positions(search.context, q, frozen=np.zeros(len(q), dtype=bool))
            search.objects.freeze_far_from(search.context, p)
            search.set_target(names[k])
            search.set_robot(orient.hover_arm(search.object_position()), ALLEGRO_OPEN_Q)
            search.refresh_sampled_outputs()
            history = np.tile(search.observation(), (HISTORY, 1))
            buffer.append(search.get_state(), history, 0.0, True)
            keys.append({"pile": number, "block": names[k], "type": block_type,
                         **start_keys(q[blocks], blocks.index(k))})
            if limit is not None and len(keys) >= limit:
                break
        if limit is not None and len(keys) >= limit:
            break
    buffer.save(out)
    Path(f"{out}.keys.json").write_text(json.dumps(keys, indent=1) + "\n")
    return len(keys)


def table(out: Path, rollout: Path) -> str:
    """Orient's success from the rollout ``rollout`` (episode i from start i) by each key of the starts."""
    keys = json.loads(Path(f"{out}.keys.json").read_text())
    missing = sorted(set(KEYS) - set(keys[0])) if keys else []
    if missing:
        raise ValueError(f"{out}.keys.json has no {', '.join(missing)}: written by an older pile_starts.py; write "
                         f"the starts again (pile_starts.py --out {out})")
    episodes = json.loads(rollout.read_text())["per_episode"]
    starts = [keys[episode["seed"] % len(keys)] for episode in episodes]  # Episode seed s starts from s mod N.
    for start, episode in zip(starts, episodes, strict=True):
        if episode.get("object") != start["block"]:
            raise ValueError(f"{rollout} episode with seed {episode['seed']} ran {episode.get('object')}, but that "
                             f"start of {out} is {start['block']}: a rollout from other starts?")
    rows = [f"Orient from {len(episodes)} starts in the pile: {sum(e['success'] for e in episodes)} succeeded"]
    for label, only in (("", lambda start: True), ("not upright, ", lambda start: not start["upright"])):
        for key in KEYS[1:] if label else KEYS:  # Upright blocks have nothing to roll: the keys among the others.
            counts = collections.defaultdict(lambda: [0, 0])
            for start, episode in zip(starts, episodes, strict=True):
                if only(start):
                    counts[start[key]][0] += bool(episode["success"])
                    counts[start[key]][1] += 1
            rows.append(f"  {label}{key}: " + ", ".join(f"{value}: {s} / {n}"
                                                         for value, (s, n) in sorted(counts.items())))
    return "\n".join(rows)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="the hand-off buffer to write (.npz; keys beside it)")
    parser.add_argument("--types", type=int, nargs="+", default=[1, 2, 3, 4, 5, 6],
                        help="block types (default 1-6: the 1xN bricks Orient's roll is for)")
    parser.add_argument("--limit", type=int, help="at most this many starts (default: all)")
    parser.add_argument("--table", metavar="ROLLOUT_JSON",
                        help="instead of writing, break a rollout from --out's starts down by the pick's keys")
    args = parser.parse_args(argv)
    out = Path(args.out)
    if args.table:
        try:
            print(table(out, Path(args.table)))
        except (OSError, ValueError, KeyError) as error:
            print(f"pile_starts: error: {error}", file=sys.stderr)
            return 2
        return 0
    if args.limit is not None and args.limit < 1:
        parser.error(f"--limit must be >= 1, got {args.limit}")
    if not set(args.types) <= set(range(1, 9)):
        parser.error(f"--types must be block types 1-8, got {args.types}")
    out.parent.mkdir(parents=True, exist_ok=True)
    count = write_starts(out, args.types, args.limit)
    print(f"pile_starts: wrote {count} Orient starts to {out} (keys in {out}.keys.json)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
