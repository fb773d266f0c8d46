"""A markdown table of ``seqdex rollout --out`` files: one row per (sub-task, object kind), the successes per file
(each file one seed), pooled, and the mean ± std of the per-seed success rates.

    python scripts/rollout_table.py results/building_blocks/per_type/*.json

Each file's episodes are counted by the object they started with (its ``per_object`` counts, which ``seqdex
rollout`` writes: ``block_6_3`` counts as ``block 6``), so a file of mixed types fills several rows. Files written
before rollouts recorded objects are refused, naming them.
"""

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np


def load(paths: list[Path]) -> dict:
    """{(task, kind): [(seed, episodes, successes), ...]} from the rollout files; ValueError naming a bad file."""
    rows: dict[tuple, list] = defaultdict(list)
    for path in paths:
        try:
            result = json.loads(path.read_text())
            task, seed = result["task"], int(result["seed"])
        except (OSError, ValueError, KeyError, TypeError) as error:
            raise ValueError(f"{path}: not a seqdex rollout --out file ({error})") from error
        if "per_object" not in result:
            raise ValueError(f"{path}: its episodes do not record their object (written before seqdex rollout "
                             f"did); roll it out again")
        for kind, counts in result["per_object"].items():
            rows[(task, kind)].append((seed, counts["episodes"], counts["successes"]))
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
