"""experiments/pile_starts.py: Orient's starts inside the cached pile as a hand-off buffer that ``seqdex rollout
--scene``
runs with the pile kept, their pick keys, and the table that joins a rollout with them."""

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "experiments" / "pile_starts.py"


def pile_starts(*args, timeout=300):
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=timeout,
                          cwd=REPO)


def test_starts_keep_the_pile_and_hover_the_hand_over_the_block(tmp_path):
    from seqdex_drake.cli.train import load_initial_states
    from seqdex_drake.env_state import EnvState
    from seqdex_drake.envs.subtask_env import make_env
    from seqdex_drake.observation_layout import rotation_matrix
    from seqdex_drake.robots.allegro import p_PalmHc_Palm
    from seqdex_drake.scene.piles import InsideBox
    from seqdex_drake.tasks.registry import budget_config

    out = tmp_path / "starts.npz"
    result = pile_starts("--out", str(out), "--limit", "2", "--types", "4")
    assert result.returncode == 0, result.stderr[-2000:]
    keys = json.loads(Path(f"{out}.keys.json").read_text())
    assert [k["type"] for k in keys] == [4, 4] and all(k["block"].startswith("block_4_") for k in keys)
    assert {"upright", "covered", "side", "quarter", "roll_blocked", "along_jaws", "on_floor"} <= set(keys[0])

    buffer = load_initial_states(str(out), "orient")
    env = make_env("orient", dataclasses.replace(budget_config("orient"), scenario="building_blocks/search"))
    env.reset(seed=0, options={"initial_state": buffer.state(1, EnvState)})
    assert env.target_object == keys[1]["block"]
    q = env.objects.positions(env.context)
    assert InsideBox(q).all()  # The whole pile, not parked: a state of the same scene restores it as it was.
    o, block = env.observation(), env.object_position()
    hand = o[98:101] + rotation_matrix(o[101:105]) @ p_PalmHc_Palm  # The hand centre.
    np.testing.assert_allclose(hand, block + [0.0, 0.0, env.config.hover_height], atol=0.01)  # Hovering over it.


def test_table_joins_a_rollout_by_episode_seed_and_refuses_other_starts(tmp_path):
    out = tmp_path / "starts.npz"
    keys = [{"pile": 0, "block": f"block_1_{k}", "type": 1, "tilt": 90.0, "upright": False, "covered": k == 1,
             "side": True, "quarter": True, "roll_blocked": k > 0, "along_jaws": False, "on_floor": False}
            for k in range(3)]
    Path(f"{out}.keys.json").write_text(json.dumps(keys))
    episodes = [{"seed": s, "object": f"block_1_{s % 3}", "success": s % 3 == 0} for s in range(4)]
    rollout = tmp_path / "rollout.json"
    rollout.write_text(json.dumps({"per_episode": episodes}))
    result = pile_starts("--out", str(out), "--table", str(rollout))
    assert result.returncode == 0, result.stderr
    assert "4 starts in the pile: 2 succeeded" in result.stdout
    assert "roll_blocked: False: 2 / 2, True: 0 / 2" in result.stdout  # Seeds 0 and 3 both start from entry 0.
    episodes[1]["object"] = "block_2_0"
    rollout.write_text(json.dumps({"per_episode": episodes}))
    result = pile_starts("--out", str(out), "--table", str(rollout))
    assert result.returncode == 2 and "a rollout from other starts?" in result.stderr
    assert "Traceback" not in result.stderr
    Path(f"{out}.keys.json").write_text(json.dumps([{k: v for k, v in key.items() if k != "quarter"} for key in keys]))
    result = pile_starts("--out", str(out), "--table", str(rollout))
    assert result.returncode == 2 and "has no quarter: written by an older pile_starts.py" in result.stderr
