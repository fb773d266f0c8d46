"""Render the Building Blocks station (Franka + Allegro, the block pile, the baseplate) to a PNG, offscreen.

The picture at the top of the README. A colour camera rendering with Drake's RenderEngineVtk (headless, CPU) is
added to the ``building_blocks/chain`` scenario, looking from where ``simulate_chain.py`` puts Meshcat's camera;
the robot is at home with the hand open, and cached pile 0 fills the box. Full visual geometry (the scenario's
low-poly perception stand-ins are off).

    python scripts/render_scene.py                       # writes docs/images/scene.png (1024 x 640)
    python scripts/render_scene.py --out scene.png --width 640 --height 400
    python scripts/render_scene.py --test                # a small image under /tmp, checks it is not blank
"""

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: Camera eye and target (world, m): behind simulate_chain.py's Meshcat camera, to fit the arm in.
EYE, TARGET = np.array([1.95, -0.55, 1.75]), np.array([0.2, -0.05, 0.92])


def camera_pose(eye: np.ndarray, target: np.ndarray):
    """X_WC of a camera at ``eye`` looking at ``target`` (Drake's camera frame: +z forward, +x right, +y down)."""
    from pydrake.math import RigidTransform, RotationMatrix

    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return RigidTransform(RotationMatrix(np.column_stack([x, np.cross(z, x), z])), eye)


def render(out: Path, width: int, height: int) -> np.ndarray:
    """Renders the scene into ``out`` (PNG); returns the RGBA pixels."""
    from pydrake.common.schema import Transform
    from pydrake.systems.sensors import CameraConfig, ImageIo

    from seqdex_drake.harness import ResolvePackageUrl
    from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q
    from seqdex_drake.scenario import LoadScenario
    from seqdex_drake.scene.objects import SceneObjects
    from seqdex_drake.scene.piles import LoadPiles
    from seqdex_drake.station import MakeStation

    scenario = LoadScenario("building_blocks/chain", scenario_text="{low_poly_perception: false}")
    scenario.cameras = {"overview": CameraConfig(name="overview", width=width, height=height, fps=10.0, rgb=True,
                                                 depth=False, label=False, focal=CameraConfig.FovDegrees(y=40),
                                                 X_PB=Transform(camera_pose(EYE, TARGET)))}
    station = MakeStation(scenario)
    context = station.CreateDefaultContext()
    objects = SceneObjects(station, scenario)
    pile = LoadPiles(ResolvePackageUrl(scenario.pile_file), objects.names)[0]
    objects.set_positions(context, pile, frozen=np.ones(len(objects.names), dtype=bool))
    plant = station.GetSubsystemByName("plant")
    plant_context = plant.GetMyMutableContextFromRoot(context)
    for name, q in (("franka", scenario.robot.arm_home), ("allegro", ALLEGRO_OPEN_Q)):
        plant.SetPositions(plant_context, plant.GetModelInstanceByName(name), np.asarray(q, dtype=float))
    image = station.GetOutputPort("overview.color_image").Eval(context)
    out.parent.mkdir(parents=True, exist_ok=True)
    ImageIo().Save(image, str(out))
    return np.array(image.data, copy=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=str(ROOT / "docs" / "images" / "scene.png"), help="the PNG to write")
    parser.add_argument("--width", type=int, default=1024)
    parser.add_argument("--height", type=int, default=640)
    parser.add_argument("--test", action="store_true", help="a 160 x 100 image under /tmp; checks it is not blank")
    args = parser.parse_args(argv)
    if args.test:
        args.out, args.width, args.height = str(Path(tempfile.mkdtemp()) / "scene.png"), 160, 100
    pixels = render(Path(args.out), args.width, args.height)
    distinct = len(np.unique(pixels[..., :3].reshape(-1, 3), axis=0))
    print(f"wrote {args.out} ({args.width} x {args.height}, {distinct} distinct colours)")
    return 0 if distinct > 20 else 1  # A blank or one-colour image: the camera saw nothing.


if __name__ == "__main__":
    sys.exit(main())
