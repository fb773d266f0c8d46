"""Shipped chain checkpoints: writing a folder, its checks (missing, truncated, wrong-task, stale-config files),
the chain runner deploying a stage with its training phases, and simulate_chain's errors."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from seqdex_drake.chaining.shipped import ShippedChainError, StageRecord, load_shipped_chain, ship_chain
from seqdex_drake.rl.config import PPOConfig
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.tasks.phases import release_tool_grasp_phases
from seqdex_drake.tasks.registry import is_scripted
from seqdex_drake.tasks.run_config import observation_spec

ROOT = Path(__file__).resolve().parents[1]
TASKS = ["tool_grasp", "tool_reorient"]
SIZES = {"tool_grasp": 159, "tool_reorient": 173}


def _checkpoint(path: Path, task: str, obs_dim: int) -> Path:
    """A small policy checkpoint for ``task`` (untrained, its observation spec recorded as seqdex train does)."""
    config = PPOConfig(actor_hidden_sizes=(16,), critic_hidden_sizes=(16,), num_envs=1)
    ppo = PPO(config, obs_dim, 19, [-1.0] * 19, [1.0] * 19)
    ppo.obs_spec = observation_spec(task, obs_dim).to_dict()
    ppo.global_step = 4096
    return ppo.save(path)


@pytest.fixture
def shipped(tmp_path) -> Path:
    # Both budget variants observe their progress: one more input than the paper's layout.
    stages = [StageRecord(task, _checkpoint(tmp_path / f"{task}.pt", task, SIZES[task] + 1),
                          "budget", 3600.0, 2) for task in TASKS]
    folder = tmp_path / "checkpoints" / "tool_positioning"
    ship_chain(folder, "tool_positioning", stages, commit="abc123")
    return folder


def test_a_shipped_folder_loads_with_its_configs_and_training_costs(shipped):
    chain = load_shipped_chain(shipped, "tool_positioning", TASKS, SIZES)
    assert chain.policies == [shipped / "stages" / task / "best.pt" for task in TASKS]
    assert chain.configs[0].phases == release_tool_grasp_phases() and chain.configs[1].phases is None
    assert chain.missing == [] and chain.feasibility == [None, None]
    stage = chain.manifest["stages"]["tool_grasp"]
    assert (stage["env_steps"], stage["wall_clock_s"], stage["core_hours"]) == (4096, 3600.0, 2.0)
    assert chain.manifest["commit"] == "abc123"


def test_missing_truncated_and_foreign_files_are_refused_naming_them(shipped, tmp_path):
    policy = shipped / "stages" / "tool_grasp" / "best.pt"
    data = policy.read_bytes()
    policy.write_bytes(data[: len(data) // 2])
    with pytest.raises(ShippedChainError, match=r"best.pt does not match its hash .* truncated"):
        load_shipped_chain(shipped, "tool_positioning", TASKS, SIZES)
    policy.unlink()
    with pytest.raises(ShippedChainError, match=r"tool_grasp/best.pt is missing \(the tool_grasp policy"):
        load_shipped_chain(shipped, "tool_positioning", TASKS, SIZES)
    # Another task's policy in the tool_grasp slot (its hash updated, as a careless copy would leave it).
    other = tmp_path / "other"
    ship_chain(other, "tool_positioning",
               [StageRecord("tool_grasp", _checkpoint(tmp_path / "reorient.pt", "tool_reorient", 173))])
    with pytest.raises(ShippedChainError, match="another task's policy or another observation layout"):
        load_shipped_chain(other, "tool_positioning", TASKS, SIZES)
    with pytest.raises(ShippedChainError, match="not 'building_blocks'"):
        load_shipped_chain(shipped, "building_blocks", ["search", "orient", "grasp", "insert"], SIZES)


def test_a_scripted_stage_is_not_shipped_and_a_policy_listed_for_it_is_refused(tmp_path):
    tasks = ["search", "retrieve", "orient", "grasp", "insert"]
    sizes = {"search": 160, "retrieve": 159, "orient": 159, "grasp": 159, "insert": 173}
    folder = tmp_path / "building_blocks"
    ship_chain(folder, "building_blocks", [StageRecord("orient", _checkpoint(tmp_path / "o.pt", "orient", 160))])
    chain = load_shipped_chain(folder, "building_blocks", tasks, sizes)
    assert chain.policies[1] is None and chain.configs[1].residual == "block_retrieve_script"
    # The missing stages are the trained ones not shipped; the scripted retrieve is not missing.
    assert [line.split(" ")[2] for line in chain.missing] == ["(search):", "(grasp):", "(insert):"]
    path = folder / "manifest.json"
    manifest = json.loads(path.read_text())
    manifest["stages"]["retrieve"] = manifest["stages"]["orient"]
    path.write_text(json.dumps(manifest))
    with pytest.raises(ShippedChainError, match="retrieve stage, which is scripted"):
        load_shipped_chain(folder, "building_blocks", tasks, sizes)
    # Shipped from a run of the learned stages alone (the pipeline trains no scripted stage): it loads as the chain.
    learned = tmp_path / "learned"
    ship_chain(learned, "building_blocks_policies", [StageRecord("orient", tmp_path / "o.pt")])
    assert load_shipped_chain(learned, "building_blocks", tasks, sizes).policies[2] is not None
    with pytest.raises(ShippedChainError, match="holds the 'building_blocks_policies' chain, not 'tool_positioning'"):
        load_shipped_chain(learned, "tool_positioning", TASKS, SIZES)


def test_a_field_added_to_the_task_config_since_shipping_is_tolerated_at_its_default(shipped):
    path = shipped / "manifest.json"
    manifest = json.loads(path.read_text())
    del manifest["stages"]["tool_grasp"]["task_config"]["scenario_overrides"]  # As a manifest shipped before it.
    path.write_text(json.dumps(manifest))
    assert load_shipped_chain(shipped, "tool_positioning", TASKS, SIZES).policies[0] is not None
    manifest["stages"]["tool_grasp"]["task_config"]["no_such_field"] = 1  # A field this code does not know.
    path.write_text(json.dumps(manifest))
    with pytest.raises(ShippedChainError, match="differs from this code's"):
        load_shipped_chain(shipped, "tool_positioning", TASKS, SIZES)


def test_a_stale_task_config_or_version_is_refused(shipped):
    path = shipped / "manifest.json"
    manifest = json.loads(path.read_text())
    manifest["stages"]["tool_grasp"]["task_config"]["episode_length"] = 99
    path.write_text(json.dumps(manifest))
    with pytest.raises(ShippedChainError, match="differs from this code's; use the code of commit abc123"):
        load_shipped_chain(shipped, "tool_positioning", TASKS, SIZES)
    manifest["version"] = 99
    path.write_text(json.dumps(manifest))
    with pytest.raises(ShippedChainError, match="version 99"):
        load_shipped_chain(shipped, "tool_positioning", TASKS, SIZES)
    path.write_text("{not json")
    with pytest.raises(ShippedChainError, match="cannot be read as JSON"):
        load_shipped_chain(shipped, "tool_positioning", TASKS, SIZES)


def test_the_chain_runner_deploys_shipped_policies_with_their_phases(shipped):
    from seqdex_drake.evaluation.runner import ChainRunner, RunConfig

    runner = ChainRunner(RunConfig(family="tool_positioning", run_dir=str(shipped)))
    assert runner.untrained == [] and runner.shipped is not None
    assert runner.policies[0].params.phases == release_tool_grasp_phases()
    assert runner.policies[1].params.phases is None
    # Both budget variants observe their progress and are residuals on their scripted bases.
    assert (runner.policies[0].params.time_steps, runner.policies[1].params.time_steps) == (150, 125)
    assert (runner.policies[0].params.residual, runner.policies[1].params.residual) == ("tool_grasp_script",
                                                                                       "tool_reorient_gait")


def test_simulate_chain_runs_shipped_checkpoints_and_refuses_broken_ones(shipped):
    command = [sys.executable, str(ROOT / "scripts" / "simulate_chain.py"), "--task", "tool_positioning",
               "--checkpoints", str(shipped), "--test", "--headless"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "every stage has a trained policy" in done.stdout
    (shipped / "stages" / "tool_reorient" / "best.pt").unlink()
    broken = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert broken.returncode != 0
    assert "tool_reorient/best.pt is missing" in broken.stderr and "Traceback" not in broken.stderr


#: The shipped checkpoint folders of the repository (``checkpoints/``), each a chain's policies and F's.
REPOSITORY_FOLDERS = ["building_blocks", "tool_positioning", "baselines/building_blocks_policy_seq",
                      "baselines/tool_positioning_policy_seq", "baselines/tool_positioning_tstar",
                      "baselines/tool_positioning_no_temporal"]


def test_every_shipped_folder_of_the_repository_is_tested():
    found = sorted(str(path.parent.relative_to(ROOT / "checkpoints"))
                   for path in (ROOT / "checkpoints").rglob("manifest.json"))
    assert found == sorted(REPOSITORY_FOLDERS)


@pytest.mark.parametrize("name", REPOSITORY_FOLDERS)
def test_the_repository_s_shipped_policies_load_inference_only_and_step(name):
    """Each shipped folder loads as the chain runner loads it (hashes, observation specs, task configs); its
    policies hold no optimizer moments or env state, and each takes one step of a Drake simulation (as the chain
    controller deploys it: scripted phases, progress input, residual base) on its env's first observation; its F's
    load for their stages."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from seqdex_drake.chaining.chain import LoadChain
    from seqdex_drake.chaining.chain_files import observation_sizes
    from seqdex_drake.chaining.feasibility_io import load_feasibility
    from seqdex_drake.controller.chain_controller import StagePolicyParams
    from seqdex_drake.controller.policy import PolicySystem
    from seqdex_drake.envs.subtask_env import make_env
    from seqdex_drake.rl.checkpoint import load_checkpoint
    from seqdex_drake.rl.policy_loading import load_policy

    folder = ROOT / "checkpoints" / name
    chain_name = json.loads((folder / "manifest.json").read_text())["chain"]
    tasks, sizes = list(LoadChain(chain_name).stages), observation_sizes()
    chain = load_shipped_chain(folder, chain_name, tasks, sizes)
    assert chain.missing == [], chain.missing
    for index, (task, path, config) in enumerate(zip(tasks, chain.policies, chain.configs, strict=True)):
        if is_scripted(task):  # Its base acts alone: nothing shipped.
            assert path is None and task not in chain.manifest["stages"]
            continue
        state = load_checkpoint(path)
        assert state["optimizer"]["state"] == {} and "env" not in state, f"{path} holds training state"
        observation, _ = make_env(task, config).reset(seed=0)
        size = sizes[task]
        system = PolicySystem.from_checkpoint(path, size, StagePolicyParams(config, 1.0 / 60.0))
        builder = DiagramBuilder()
        builder.AddSystem(system)
        source = builder.AddSystem(ConstantVectorSource(np.asarray(observation[:size], dtype=float)))
        builder.Connect(source.get_output_port(), system.GetInputPort("observation"))
        simulator = Simulator(builder.Build())
        simulator.AdvanceTo(0.5 / 60.0)
        raw = system.GetOutputPort("raw_action").Eval(system.GetMyContextFromRoot(simulator.get_context()))
        assert raw.shape == (19,) and np.isfinite(raw).all() and np.abs(raw).max() <= 1.0, (path, raw)
        # The network's own output on that observation (the env's, progress included), as load_policy gives it.
        policy = load_policy(path, task=task)
        assert np.isfinite(policy(observation)).all()
        if index > 0 and chain.feasibility[index] is not None:
            previous = tasks[index - 1]
            f = load_feasibility(chain.feasibility[index], expected_target_task=task)
            assert f.source_task == previous and f.threshold > 0


def test_shipped_policies_leave_the_training_state_out_and_act_as_trained(tmp_path):
    """ship_chain writes a policy without its optimizer moments and env state; PPO.resume (the chain controller's
    loader) and load_policy read it, and it acts exactly as the training checkpoint does."""
    import torch

    from seqdex_drake.rl.checkpoint import load_checkpoint, save_checkpoint
    from seqdex_drake.rl.policy_loading import load_policy

    size = SIZES["tool_grasp"] + 1
    ppo = PPO(PPOConfig(actor_hidden_sizes=(16,), critic_hidden_sizes=(16,), num_envs=1), size, 19,
              [-1.0] * 19, [1.0] * 19)
    ppo.obs_spec = observation_spec("tool_grasp", size).to_dict()
    observations = torch.randn(8, size, generator=torch.Generator().manual_seed(0))
    ppo.model.update_normalizer(observations)
    (ppo.model.action_mean(observations).square().sum() + ppo.model.value(observations).sum()).backward()
    ppo.optimizer.step()  # Adam's moments: what a training checkpoint carries for resuming.
    state = ppo.state_dict()
    state["env"] = {"next_obs": observations}  # As a run that saved its vector env's state.
    source = save_checkpoint(tmp_path / "last.pt", state)
    assert load_checkpoint(source)["optimizer"]["state"]
    ship_chain(tmp_path / "shipped", "tool_positioning", [StageRecord("tool_grasp", source, "budget")])
    shipped = tmp_path / "shipped" / "stages" / "tool_grasp" / "best.pt"
    written = load_checkpoint(shipped)
    assert written["optimizer"]["state"] == {} and "env" not in written
    assert shipped.stat().st_size < source.stat().st_size
    original = load_checkpoint(source)
    assert written["model"].keys() == original["model"].keys()
    for key, value in original["model"].items():
        assert torch.allclose(written["model"][key], value, rtol=0, atol=0, equal_nan=True), key
    for key in ("counters", "config", "dims", "best", "obs_spec"):
        assert written[key] == original[key], key
    chain = load_shipped_chain(tmp_path / "shipped", "tool_positioning", TASKS, SIZES)
    assert chain.policies[0] == shipped
    inputs = np.random.default_rng(1).normal(size=(16, size)).astype(np.float32)
    assert load_policy(shipped)(inputs).tobytes() == load_policy(source)(inputs).tobytes()
    with torch.no_grad():
        resumed = [PPO.resume(path, device="cpu").model.action_mean(torch.as_tensor(inputs)) for path in (source,
                                                                                                       shipped)]
    assert torch.equal(*resumed)
