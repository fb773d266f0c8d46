"""Paired comparisons of ``seqdex evaluate`` rows over the same episodes, with exact McNemar tests, as Markdown.

    python scripts/paired_table.py --row switcher=results/tool_positioning/eval_switcher \
        --row sequential=results/tool_positioning/eval_sequential --pair switcher:sequential [--out table.md]

Each ``--row NAME=DIR`` names an evaluation output directory (its ``episodes.jsonl``) or a main-command record (a
``.json`` of ``experiments/main_command_seeds.py``, a block per seed and manual step); each ``--pair A:B`` adds a
line: the episodes both rows played, their successes, the four cells and the McNemar p-value
(:mod:`seqdex_drake.evaluation.paired`).
"""

import argparse
import sys

from seqdex_drake.atomic import atomic_write
from seqdex_drake.evaluation.paired import paired_table
from seqdex_drake.user_input import InputError, check_creatable


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--row", action="append", required=True, metavar="NAME=DIR",
                        help="a row: its name and a seqdex evaluate output directory or main_command_seeds.py "
                             "record (repeat)")
    parser.add_argument("--pair", action="append", required=True, metavar="A:B", help="compare rows A and B (repeat)")
    parser.add_argument("--out", help="also write the table to this Markdown file")
    return parser.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        rows = {}
        for entry in args.row:
            name, sep, path = entry.partition("=")
            if not sep or not name or not path:
                raise InputError(f"--row {entry!r}: write NAME=DIR")
            rows[name] = path
        pairs = []
        for entry in args.pair:
            first, sep, second = entry.partition(":")
            if not sep or not first or not second:
                raise InputError(f"--pair {entry!r}: write A:B with two row names")
            pairs.append((first, second))
        if args.out:
            check_creatable(args.out, "--out")
        table = paired_table(pairs, rows)
    except (InputError, ValueError, FileNotFoundError) as error:
        print(f"paired_table: error: {error}", file=sys.stderr)
        return 2
    print(table, end="")
    if args.out:
        atomic_write(args.out, lambda file: file.write(table.encode()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
