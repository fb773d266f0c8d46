"""Run a whole Sequential Dexterity task in Drake, live in meshcat: the README's main command.

The same as ``seqdex simulate`` (:mod:`seqdex_drake.cli.simulate`), with the same flags::

    python scripts/simulate_chain.py                                  # meshcat URL printed; Ctrl-C to stop
    python scripts/simulate_chain.py --manual mixed_shapes --checkpoints runs/chain
    python scripts/simulate_chain.py --task tool_positioning --record replay.html
    python scripts/simulate_chain.py --test --headless                # a short run for CI, exits 0
"""

import sys

from seqdex_drake.cli.main import main

if __name__ == "__main__":
    sys.exit(main(["simulate", *sys.argv[1:]]))
