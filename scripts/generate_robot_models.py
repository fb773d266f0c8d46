"""Regenerate the robot model files under models/ (Franka Panda arm and Allegro right hand).

python scripts/generate_robot_models.py                    # rewrites models/franka, models/allegro
python scripts/generate_robot_models.py --output-dir /tmp/m  # writes elsewhere (e.g. to compare)
python scripts/generate_robot_models.py --test             # writes to a temporary directory, checks that
                                                           # it matches the committed files, exits 0/1
"""

import argparse
import sys
import tempfile
from pathlib import Path

from seqdex_drake.modeling.robot_models import MODELS_DIR, ROBOT_MODEL_FILES, write_robot_models


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--output-dir", type=Path, default=MODELS_DIR, help="models root (default: models/)")
    parser.add_argument("--test", action="store_true", help="generate into a temp dir and compare with models/")
    args = parser.parse_args(argv)
    if not args.test:
        for path in write_robot_models(args.output_dir):
            print(f"wrote {path}")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        write_robot_models(tmp)
        stale = [
            relative
            for relative in ROBOT_MODEL_FILES
            if not (MODELS_DIR / relative).exists()
            or (MODELS_DIR / relative).read_bytes() != (Path(tmp) / relative).read_bytes()
        ]
    for relative in stale:
        print(f"out of date: models/{relative} (run scripts/generate_robot_models.py)")
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())
