"""Drop the 72 blocks into the box, let them settle, and cache the piles for instant restores.

    python scripts/generate_piles.py [--count 8] [--seed 0] [--out models/piles/building_blocks_piles.npz]

Each pile is checked (every block inside the box) before it is kept; the file is written atomically.
"""

import argparse
import sys
import time

import numpy as np

from seqdex_drake import LoadScenario
from seqdex_drake.harness import MakeStationHarness, ResolvePackageUrl
from seqdex_drake.scene.piles import SETTLE_TIME_STEP, InsideBox, PileSettings, SavePiles, SettlePile


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--count", type=int, default=8, help="number of piles to keep")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first pile (pile k uses seed + k)")
    parser.add_argument("--scenario", default="building_blocks/search")
    parser.add_argument("--out", default=None, help="output file (default: the scenario's pile_file)")
    parser.add_argument("--time-step", type=float, default=SETTLE_TIME_STEP,
                        help=f"plant step of the settling (default {SETTLE_TIME_STEP} s: finer than Search's own "
                        "1/240 s, so the cached piles rest as they did before Search's step grew)")
    parser.add_argument("--test", action="store_true", help="one pile, written to --out (required)")
    args = parser.parse_args(argv)
    if args.test and args.out is None:
        parser.error("--test needs --out so the shipped cache is not overwritten")
    if not 0 < args.time_step <= 0.01:
        parser.error(f"--time-step must be in (0, 0.01] s, got {args.time_step}")
    scenario = LoadScenario(args.scenario, scenario_text="{object_layout: parked, freeze: {enabled: false}, "
                            f"plant_config: {{time_step: {args.time_step!r}}}}}")
    out = args.out or ResolvePackageUrl(scenario.pile_file)
    harness = MakeStationHarness(scenario)
    piles, seed = [], args.seed
    count = 1 if args.test else args.count
    while len(piles) < count:
        start = time.perf_counter()
        q = SettlePile(harness.simulator, harness.objects, seed, PileSettings())
        inside = InsideBox(q)
        print(f"pile seed {seed}: {inside.sum()}/{len(q)} blocks inside the box, "
              f"{time.perf_counter() - start:.1f} s", flush=True)
        if inside.all():
            piles.append(q)
        seed += 1
        if len(piles) < count and seed - args.seed >= 3 * count:
            print("error: too many piles lost blocks; check the contact settings", file=sys.stderr)
            return 1
    SavePiles(out, np.array(piles), harness.objects.names, args.scenario)
    print(f"wrote {len(piles)} piles to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
