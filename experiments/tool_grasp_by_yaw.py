"""Tool Grasp's success by the tool's start yaw, from rollout records of the same episodes.

Each record is what ``seqdex rollout --task tool_grasp ... --out R.json`` wrote; its episodes are reset again (the
env's reset with the episode's seed lays the tool at the yaw that episode started from; nothing is simulated past
the reset) and binned by that yaw, so records of different grasps over the same seeds line up bin by bin::

    python experiments/tool_grasp_by_yaw.py results/tool_positioning/tool_grasp_script_seed3000.json \\
        results/tool_positioning/tool_pinch_seed3000.json --bins 8
    python experiments/tool_grasp_by_yaw.py --test R.json     # the first 4 episodes, for CI

Prints one Markdown table: a row per yaw bin (the reset's range, +-45 deg, cut in ``--bins``), the episodes in it
and each record's successes there.
"""

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

#: The start yaw's range (rad): ``tasks/tools_common.place_tool_on_table``'s +-45 deg.
YAW_RANGE = np.pi / 4


def start_yaws(env, episodes: list[dict]) -> np.ndarray:
    """The tool's yaw (rad, its long axis y's heading about world z) after the reset of each episode's seed."""
    from seqdex_drake.observation_layout import rotation_matrix

    yaws = []
    for episode in episodes:
        env.reset(seed=int(episode["seed"]))
        R_WT = rotation_matrix(env.raw_observation()[114:118])
        yaws.append(float(np.arctan2(-R_WT[0, 1], R_WT[1, 1])))
    return np.array(yaws)


def load_records(paths: list[str], limit: int | None) -> tuple[list[dict], list[list[bool]]]:
    """The episodes (seed, object) of the first record and each record's successes, checked to be the same
    episodes in every record. Raises SystemExit with a message for a missing, malformed or mismatched record."""
    episodes, successes = None, []
    for path in paths:
        try:
            record = json.loads(Path(path).read_text())
            rows = record["per_episode"][:limit]
        except (OSError, ValueError, KeyError, TypeError) as error:
            sys.exit(f"tool_grasp_by_yaw: {path} is not a rollout record ({error}); give the JSON `seqdex rollout "
                     "--task tool_grasp --out` wrote")
        if record.get("task") != "tool_grasp":
            sys.exit(f"tool_grasp_by_yaw: {path} is a {record.get('task')!r} rollout, not tool_grasp")
        keys = [(row["seed"], row["object"]) for row in rows]
        if episodes is None:
            episodes = [{"seed": seed, "object": name} for seed, name in keys]
        elif keys != [(e["seed"], e["object"]) for e in episodes]:
            sys.exit(f"tool_grasp_by_yaw: {path} holds other episodes than {paths[0]}; give records of the same "
                     "--seed and --episodes")
        successes.append([bool(row["success"]) for row in rows])
    return episodes, successes


def table(paths: list[str], yaws: np.ndarray, successes: list[list[bool]], bins: int) -> str:
    edges = np.linspace(-YAW_RANGE, YAW_RANGE, bins + 1)
    names = [Path(path).stem for path in paths]
    lines = ["| Start yaw (rad) | Episodes | " + " | ".join(names) + " |", "|---" * (2 + len(names)) + "|"]
    for low, high in zip(edges[:-1], edges[1:], strict=True):
        inside = (yaws >= low) & ((yaws < high) | (high == edges[-1]))
        cells = [f"{int(np.sum(np.asarray(s)[inside]))}" for s in successes]
        lines.append(f"| {low:+.2f} .. {high:+.2f} | {int(inside.sum())} | " + " | ".join(cells) + " |")
    totals = [f"{sum(s)}" for s in successes]
    lines.append(f"| all | {len(yaws)} | " + " | ".join(totals) + " |")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("records", nargs="+", help="tool_grasp rollout records of the same episodes")
    parser.add_argument("--bins", type=int, default=8, help="yaw bins over +-45 deg (default 8)")
    parser.add_argument("--test", action="store_true", help="the first 4 episodes only")
    args = parser.parse_args(argv)
    if args.bins < 1:
        parser.error(f"--bins must be at least 1, got {args.bins}")
    episodes, successes = load_records(args.records, 4 if args.test else None)
    objects = sorted({e["object"] for e in episodes})
    from seqdex_drake.envs.subtask_env import make_env
    from seqdex_drake.modeling.tools import TOOL_SPECS
    from seqdex_drake.tasks.registry import budget_config

    if len(objects) != 1 or objects[0] not in TOOL_SPECS:
        parser.error(f"the records must hold episodes of one tool (of {', '.join(TOOL_SPECS)}), got {objects}")
    config = dataclasses.replace(budget_config("tool_grasp"), object_types=[list(TOOL_SPECS).index(objects[0])])
    yaws = start_yaws(make_env("tool_grasp", config), episodes)
    print(table(args.records, yaws, successes, args.bins))


if __name__ == "__main__":
    main()
