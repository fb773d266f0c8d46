"""What the Search scene's physics settings buy: Search / Grasp env steps/s with the shipped settings and without.

The Search scene steps its plant at 1/240 s and uses a faster-sleeping freezer (``diagrams/
building_blocks.scenarios.yaml``; ``docs/architecture.md`` "Search's step"). This script measures
``env_throughput.search_over_grasp`` (Search and Grasp envs in this process, random actions, interleaved in
chunks) with the Search scenario as shipped, with each change alone, and with the former settings (2 ms plant
steps, the default freezer), the variants alternating ``--repeats`` times, each ratio summed over its passes.
Every ratio is Search's rate over Grasp's measured beside it, so the machine's drift weighs on both alike.

    python benchmarks/search_settings.py [--search-steps 30] [--repeats 2] [--test]

The last line is one JSON object: ``search_env_over_grasp_env`` per variant and ``gain`` (shipped / former).
"""

import argparse
import json
import os

from env_throughput import search_over_grasp

FORMER_FREEZER = "freeze: {enabled: true, wake_radius: 0.09, wake_speed: 0.1, sleep_speed: 0.01, sleep_ticks: 30}"
VARIANTS = {
    "shipped": "{}",
    "step_only": "{" + FORMER_FREEZER + "}",  # 1/240 s, the default freezer.
    "freezer_only": "{plant_config: {time_step: 0.002}}",  # 2 ms, the shipped freezer.
    "former": "{plant_config: {time_step: 0.002}, " + FORMER_FREEZER + "}",
}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--search-steps", type=int, default=30, help="Search steps per variant and repeat")
    parser.add_argument("--repeats", type=int, default=2, help="alternating passes over the variants")
    parser.add_argument("--test", action="store_true", help="a few steps, the shipped and former settings only")
    args = parser.parse_args(argv)
    steps, repeats = (5, 1) if args.test else (args.search_steps, args.repeats)
    # The quick mode checks the script and its keys: the shipped and the former settings only.
    variants = {name: VARIANTS[name] for name in ("shipped", "former")} if args.test else VARIANTS
    load = os.getloadavg()[0]
    totals = {name: {"search_steps": 0, "search_s": 0.0, "grasp_steps": 0, "grasp_s": 0.0} for name in variants}
    for _ in range(repeats):
        for name, text in variants.items():
            result = search_over_grasp(steps, 1, search_overrides=text)
            for env in ("search", "grasp"):  # Rates from summed steps and times, not means of rates.
                totals[name][f"{env}_steps"] += result[f"{env}_steps"]
                totals[name][f"{env}_s"] += result[f"{env}_steps"] / result[f"{env}_env_steps_per_s"]
            print(f"{name:12s} {result}", flush=True)
    ratios = {}
    for name, total in totals.items():
        search_rate, grasp_rate = (total[f"{env}_steps"] / total[f"{env}_s"] for env in ("search", "grasp"))
        ratios[name] = {"search_env_over_grasp_env": round(search_rate / grasp_rate, 4),
                        "search_env_steps_per_s": round(search_rate, 2), "grasp_env_steps_per_s": round(grasp_rate, 2)}
    summary = {"variants": ratios, "overrides": variants,
               "gain": round(ratios["shipped"]["search_env_over_grasp_env"]
                             / ratios["former"]["search_env_over_grasp_env"], 3),
               "search_steps": steps, "repeats": repeats, "load_average": round(load, 2)}
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
