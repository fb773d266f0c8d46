"""A markdown table of ``seqdex rollout --out`` files: one row per (sub-task, object kind), the successes per file
(each file one seed), pooled, and the mean ± std of the per-seed success rates.

    python scripts/rollout_table.py results/building_blocks/unseen/*.json

Each file's episodes are counted by the object they started with (``per_episode[i]["object"]``, recorded by
``seqdex rollout``; ``block_6_3`` counts as ``block 6``), so a file of mixed types fills several rows. Files
written before rollouts recorded objects are refused, naming them.
"""

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from seqdex_drake.cli.rollout import object_kind  # noqa: E402


def load(paths: list[Path]) -> dict:
    """{(task, kind): [(seed, episodes, successes), ...]} from the rollout files; ValueError naming a bad file."""
    rows: dict[tuple, list] = defaultdict(list)
    for path in paths:
        try:
            result = json.loads(path.read_text())
            task, episodes = result["task"], result["per_episode"]
        except (OSError, ValueError, KeyError, TypeError) as error:
            raise ValueError(f"{path}: not a seqdex rollout --out file ({error})") from error
        if any("object" not in episode for episode in episodes):
            raise ValueError(f"{path}: its episodes do not record their object (written before seqdex rollout "
                             f"did); roll it out again")
        counts: dict[str, list[int]] = defaultdict(lambda: [0, 0])
        for episode in episodes:
            count = counts[object_kind(episode["object"])]
            count[0] += 1
            count[1] += int(episode["success"])
        for kind, (total, successes) in counts.items():
            rows[(task, kind)].append((int(result["seed"]), total, successes))
    return rows


def table(rows: dict) -> str:
    lines = ["| Sub-task | Object | Per seed (successes / episodes) | All | Mean ± std over seeds |",
             "|---|---|---|---|---|"]
    for (task, kind), entries in sorted(rows.items()):
        entries = sorted(entries)
        rates = np.array([successes / total for _, total, successes in entries])
        total = sum(entry[1] for entry in entries)
        successes = sum(entry[2] for entry in entries)
        per_seed = ", ".join(f"{s}/{n}" for _, n, s in entries)
        lines.append(f"| {task} | {kind} | {per_seed} | {successes} / {total} ({successes / total:.2f}) | "
                     f"{rates.mean():.2f} ± {rates.std():.2f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+", type=Path, help="seqdex rollout --out JSON files")
    args = parser.parse_args(argv)
    try:
        rows = load(args.files)
    except ValueError as error:
        print(f"rollout_table: {error}", file=sys.stderr)
        return 2
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
