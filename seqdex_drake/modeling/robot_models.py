"""Generates the robot models (Franka Panda arm, Allegro right hand) as Drake-parsable URDF files.

The text of each file is a pure function of the Python data in `franka_model`, `allegro_model` and
`seqdex_drake.robots`, so running `scripts/generate_robot_models.py` reproduces the committed files byte for
byte (a test checks this).
"""

from pathlib import Path

from seqdex_drake.modeling.allegro_model import build_allegro_right_urdf
from seqdex_drake.modeling.franka_model import build_panda_urdf

MODELS_DIR = Path(__file__).resolve().parents[2] / "models"
"""The repository's `models/` directory: the root of the `seqdex_models` package."""

ROBOT_MODEL_FILES = {
    "franka/panda_arm.urdf": build_panda_urdf,
    "allegro/allegro_right.urdf": build_allegro_right_urdf,
}
"""Relative path under `models/` -> function returning that file's text."""


def write_robot_models(models_dir: Path | str = MODELS_DIR) -> list[Path]:
    """Writes every robot model under `models_dir` (creating subdirectories) and returns the paths written."""
    models_dir = Path(models_dir)
    written = []
    for relative_path, build in ROBOT_MODEL_FILES.items():
        path = models_dir / relative_path
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(build(), encoding="utf-8", newline="\n")
        written.append(path)
    return written
