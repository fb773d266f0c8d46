"""Forward initialization's hand-off file: round trip, version and spec checks, messages, atomic writes."""

import dataclasses
import json

import numpy as np
import pytest

from seqdex_drake.chaining import terminal_buffer as terminal_buffer_module
from seqdex_drake.chaining.terminal_buffer import TerminalBuffer
from seqdex_drake.observation_spec import ObservationSpec

SPEC = ObservationSpec(4, "toy: q(2) dq(2)")


@dataclasses.dataclass
class FakeEnvState:
    """Shaped like the env's EnvState: arrays, a str and a dict of arrays."""

    plant_positions: np.ndarray
    plant_velocities: np.ndarray
    objects: dict
    target_object: str
    goal: np.ndarray


def make_state(rng, index: int) -> FakeEnvState:
    return FakeEnvState(plant_positions=rng.normal(size=9), plant_velocities=rng.normal(size=8),
                        objects={"frozen": rng.random(5) > 0.5, "q_pin": rng.normal(size=(5, 7)),
                                 "still_ticks": rng.integers(0, 9, 5)},
                        target_object=f"block_{index}" * (1 + index % 2), goal=rng.normal(size=7))


def filled_buffer(count: int = 5, seed: int = 0) -> tuple[TerminalBuffer, list, list, list]:
    rng = np.random.default_rng(seed)
    buffer = TerminalBuffer("grasp", "insert", "blocks.yaml", SPEC, history=3)
    states, histories, returns = [], [], []
    for index in range(count):
        states.append(make_state(rng, index))
        histories.append(rng.normal(size=(3 + index, 4)).astype(np.float32))
        returns.append(float(rng.normal()))
        buffer.append(states[-1], histories[-1], returns[-1], success=index % 2 == 0)
    return buffer, states, histories, returns


def assert_same_state(restored: FakeEnvState, original: FakeEnvState):
    assert isinstance(restored, FakeEnvState)
    for field in ("plant_positions", "plant_velocities", "goal"):
        np.testing.assert_array_equal(getattr(restored, field), getattr(original, field))
    assert restored.target_object == original.target_object and isinstance(restored.target_object, str)
    for key, value in original.objects.items():
        np.testing.assert_array_equal(restored.objects[key], value)
        assert restored.objects[key].dtype == value.dtype


def test_round_trip(tmp_path):
    buffer, states, histories, returns = filled_buffer()
    path = buffer.save(tmp_path / "buffers" / "grasp_to_insert.npz")
    loaded = TerminalBuffer.load(path, expected_task="insert", expected_obs_spec=SPEC, expected_source="grasp",
                                 expected_scenario="blocks.yaml")
    assert len(loaded) == 5 and loaded.history == 3 and loaded.obs_spec == SPEC
    assert (loaded.source_task, loaded.target_task, loaded.scenario) == ("grasp", "insert", "blocks.yaml")
    np.testing.assert_array_equal(loaded.histories, np.stack([h[-3:] for h in histories]))
    np.testing.assert_array_equal(loaded.returns, returns)
    np.testing.assert_array_equal(loaded.successes, [True, False, True, False, True])
    for index, state in enumerate(states):
        assert_same_state(loaded.state(index, FakeEnvState), state)
    nested = loaded.state(1)
    assert set(nested) == {"plant_positions", "plant_velocities", "objects", "target_object", "goal"}
    assert set(nested["objects"]) == {"frozen", "q_pin", "still_ticks"}


def test_plain_mappings_and_python_scalars_round_trip(tmp_path):
    buffer = TerminalBuffer("a", "b", "s", SPEC, history=1)
    buffer.append({"q": np.arange(3.0), "step": 7, "scale": 0.5, "done": True, "name": "x"}, np.ones((1, 4)), 1.0)
    state = TerminalBuffer.load(buffer.save(tmp_path / "b.npz")).state(0)
    assert state["step"] == 7 and isinstance(state["step"], int)
    assert state["scale"] == 0.5 and isinstance(state["scale"], float)
    assert state["done"] is True and state["name"] == "x"
    np.testing.assert_array_equal(state["q"], np.arange(3.0))


def test_sample_draws_entries():
    buffer, states, _, returns = filled_buffer(count=6)
    rng = np.random.default_rng(0)
    seen = {buffer.sample(rng).episode_return for _ in range(200)}
    assert seen == set(returns)
    for _ in range(20):
        entry = buffer.sample(rng, FakeEnvState, successful_only=True)
        index = returns.index(entry.episode_return)
        assert entry.success and index % 2 == 0
        assert_same_state(entry.state, states[index])
        assert entry.history.shape == (3, 4)
    with pytest.raises(ValueError, match="no entries"):
        TerminalBuffer("a", "b", "s", SPEC, history=2).sample(rng)


def test_append_rejects_mismatched_entries():
    buffer, *_ = filled_buffer(count=1)
    rng = np.random.default_rng(1)
    state = make_state(rng, 0)
    with pytest.raises(ValueError, match="history must be"):
        buffer.append(state, np.zeros((2, 4)), 0.0)  # Shorter than H.
    with pytest.raises(ValueError, match="history must be"):
        buffer.append(state, np.zeros((3, 5)), 0.0)
    with pytest.raises(ValueError, match="plant_positions"):
        buffer.append(dataclasses.replace(state, plant_positions=np.zeros(10)), np.zeros((3, 4)), 0.0)
    with pytest.raises(ValueError, match="differ"):
        buffer.append({"other": np.zeros(2)}, np.zeros((3, 4)), 0.0)
    with pytest.raises(TypeError):
        buffer.append([1, 2], np.zeros((3, 4)), 0.0)
    assert len(buffer) == 1


def test_missing_file_names_the_command(tmp_path):
    with pytest.raises(FileNotFoundError, match="seqdex collect --task grasp"):
        TerminalBuffer.load(tmp_path / "none.npz", expected_task="insert", expected_source="grasp")
    with pytest.raises(FileNotFoundError, match="seqdex collect --task"):
        TerminalBuffer.load(tmp_path / "none.npz")


def test_task_scenario_and_spec_mismatches(tmp_path):
    buffer, *_ = filled_buffer(count=2)
    path = buffer.save(tmp_path / "b.npz")
    with pytest.raises(ValueError, match="target task 'insert'.*'orient'"):
        TerminalBuffer.load(path, expected_task="orient")
    with pytest.raises(ValueError, match="source task 'grasp'.*'search'"):
        TerminalBuffer.load(path, expected_source="search")
    with pytest.raises(ValueError, match="scenario"):
        TerminalBuffer.load(path, expected_scenario="tools.yaml")
    other = ObservationSpec(4, "toy: q(2) torque(2)")
    with pytest.raises(ValueError) as error:
        TerminalBuffer.load(path, expected_obs_spec=other)
    assert "toy: q(2) dq(2)" in str(error.value) and "toy: q(2) torque(2)" in str(error.value)


def test_version_and_format_checks(tmp_path):
    buffer, *_ = filled_buffer(count=2)
    path = buffer.save(tmp_path / "b.npz")
    with np.load(path, allow_pickle=False) as data:
        arrays = {key: data[key] for key in data.files}
    meta = json.loads(str(arrays["meta"]))
    meta["version"] = 99
    np.savez(tmp_path / "future.npz", **{**arrays, "meta": np.asarray(json.dumps(meta))})
    with pytest.raises(ValueError, match="version 99.*version 1"):
        TerminalBuffer.load(tmp_path / "future.npz")
    meta["format"] = "something else"
    np.savez(tmp_path / "foreign.npz", **{**arrays, "meta": np.asarray(json.dumps(meta))})
    with pytest.raises(ValueError, match="not a terminal buffer"):
        TerminalBuffer.load(tmp_path / "foreign.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match="not a readable terminal buffer"):
        TerminalBuffer.load(tmp_path / "junk.npz")


def test_failed_write_leaves_the_old_file(tmp_path, monkeypatch):
    old, *_ = filled_buffer(count=2, seed=0)
    path = old.save(tmp_path / "b.npz")
    new, *_ = filled_buffer(count=4, seed=1)

    def crash_mid_write(file, **arrays):
        file.write(b"PK\x03\x04 half a zip")
        raise OSError("disk full")

    monkeypatch.setattr(terminal_buffer_module.np, "savez", crash_mid_write)
    with pytest.raises(OSError, match="disk full"):
        new.save(path)
    monkeypatch.undo()
    assert [p.name for p in tmp_path.iterdir()] == ["b.npz"]  # The temporary file was removed.
    loaded = TerminalBuffer.load(path)
    assert len(loaded) == 2
    np.testing.assert_array_equal(loaded.returns, old.returns)
    new.save(path)
    assert len(TerminalBuffer.load(path)) == 4
