"""Regenerate the scene assets under models/: Mega Bloks, fixtures, tools and the 72-block pile directives.

    python scripts/generate_assets.py                       # everything into models/ (about a minute)
    python scripts/generate_assets.py --only block_7        # one asset (repeatable, or comma-separated)
    python scripts/generate_assets.py --out /tmp/m --jobs 2 # elsewhere, two worker processes
    python scripts/generate_assets.py --test                # blocks, fixtures and directives into a temp
                                                            # dir, compared with models/ byte for byte; 0/1

Assets: block_1 ... block_8, table, box, baseplate, plate_1, plate_2, plate_3, hammer, spatula, spoon, pile.
Output is deterministic: rerunning writes identical files.
"""

import argparse
import filecmp
import multiprocessing
import os
import sys
import tempfile
import time

from seqdex_drake.modeling import blocks, fixtures, tools

MODELS_DIR = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "models"))
BLOCK_ASSETS = tuple(f"block_{t}" for t in sorted(blocks.BLOCK_SPECS))
ASSETS = BLOCK_ASSETS + fixtures.FIXTURE_NAMES + tuple(tools.TOOL_SPECS) + ("pile",)
TEST_ASSETS = BLOCK_ASSETS + fixtures.FIXTURE_NAMES + ("pile",)  # All but the CoACD-decomposed tools.


def generate(name: str, out_dir: str) -> dict:
    """Generates one asset into the models root `out_dir`; returns its summary with the time taken."""
    start = time.perf_counter()
    if name in BLOCK_ASSETS:
        summary = blocks.generate_block(int(name.split("_")[1]), out_dir)
    elif name in fixtures.FIXTURE_NAMES:
        summary = fixtures.generate_fixture(name, out_dir)
    elif name in tools.TOOL_SPECS:
        summary = tools.generate_tool(name, out_dir)
    elif name == "pile":
        summary = {"name": "pile", "files": blocks.write_pile_directives(out_dir)}
    else:
        raise ValueError(f"unknown asset {name!r}; valid assets are {list(ASSETS)}")
    summary["seconds"] = time.perf_counter() - start
    return summary


def _generate_star(arguments):
    """`generate` for Pool.map (one tuple argument)."""
    return generate(*arguments)


def _describe(summary: dict) -> str:
    """One report line for an asset summary."""
    details = [f"{summary['seconds']:6.2f} s"]
    if "mass" in summary:
        details.append(f"mass {summary['mass'] * 1000:8.1f} g")
    for key in ("coarse_pieces", "fine_pieces", "pieces", "collisions"):
        if key in summary:
            details.append(f"{key} {summary[key]}")
    return f"{summary['name']:<10} " + ", ".join(details)


def run(names: list[str], out_dir: str, jobs: int) -> list[dict]:
    """Generates the named assets with `jobs` worker processes (spawned) and prints one line per asset."""
    work = [(name, out_dir) for name in names]
    if jobs > 1 and len(work) > 1:
        # Longest first (CoACD tools), so the pool stays busy.
        work.sort(key=lambda item: item[0] not in tools.TOOL_SPECS)
        with multiprocessing.get_context("spawn").Pool(jobs) as pool:
            summaries = pool.map(_generate_star, work, chunksize=1)
    else:
        summaries = [generate(*item) for item in work]
    for summary in summaries:
        print(_describe(summary), flush=True)
    return summaries


def _compare_with_models(tmp: str) -> list[str]:
    """Relative paths under blocks/, fixtures/ and the pile directives that differ from models/."""
    stale = []
    for root, _, files in os.walk(tmp):
        for file in sorted(files):
            relative = os.path.relpath(os.path.join(root, file), tmp)
            committed = os.path.join(MODELS_DIR, relative)
            if not os.path.exists(committed) or not filecmp.cmp(committed, os.path.join(tmp, relative), False):
                stale.append(relative)
    return stale


def main(argv=None) -> int:
    """Command-line entry point; returns the exit status."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", action="append", default=[], metavar="ASSET",
                        help=f"asset(s) to generate (repeatable or comma-separated): {', '.join(ASSETS)}")
    parser.add_argument("--out", default=MODELS_DIR, help="models root to write into (default: models/)")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    parser.add_argument("--test", action="store_true",
                        help="regenerate everything but the tools into a temp dir and compare with models/")
    args = parser.parse_args(argv)
    names = [name for item in args.only for name in item.split(",") if name] or list(ASSETS)
    unknown = [name for name in names if name not in ASSETS]
    if unknown:
        parser.error(f"unknown asset(s) {unknown}; valid assets are {list(ASSETS)}")
    if not args.test:
        start = time.perf_counter()
        run(names, args.out, max(1, args.jobs))
        print(f"done in {time.perf_counter() - start:.1f} s -> {args.out}")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        run([name for name in names if name in TEST_ASSETS], tmp, max(1, args.jobs))
        stale = _compare_with_models(tmp)
    for relative in stale:
        print(f"out of date: models/{relative} (run scripts/generate_assets.py)")
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())
