"""The transition feasibility function: shapes for H = 1..15, padding and masks, fitting, the temporal model's
edge over the last-state MLP, the threshold and score, and the file round trip."""

import numpy as np
import pytest
import torch

from seqdex_drake.chaining.feasibility import (
    FeasibilityConfig,
    MlpFeasibility,
    TemporalFeasibility,
    build_feasibility_model,
    feasibility_threshold,
    pad_history,
    score,
    train_feasibility,
)
from seqdex_drake.chaining.feasibility_io import load_feasibility, save_feasibility
from seqdex_drake.observation_spec import ObservationSpec

SMALL = dict(d_model=32, heads=4, layers=1, feedforward=64, dropout=0.0, mlp_hidden=(64, 64), batch_size=64, lr=1e-3)


def velocity_dataset(count: int, history: int, obs_dim: int = 3, seed: int = 0):
    """Histories whose step-to-step position noise is large, and a last-step velocity v (x[-1, 0] - x[-2, 0])
    that is small: the last observation alone says almost nothing about v."""
    rng = np.random.default_rng(seed)
    histories = rng.normal(0.0, 2.0, (count, history, obs_dim)).astype(np.float32)
    velocity = rng.normal(0.0, 0.5, count).astype(np.float32)
    histories[:, -1, 0] = histories[:, -2, 0] + velocity
    return histories, velocity


@pytest.mark.parametrize("positional", ["learned", "sinusoidal"])
def test_attention_model_handles_every_history_length(positional):
    for history in range(1, 16):
        config = FeasibilityConfig(history=history, positional=positional, **SMALL)
        model = build_feasibility_model(5, config).eval()
        assert isinstance(model, TemporalFeasibility)
        out = model(torch.randn(7, history, 5))
        assert out.shape == (7,) and torch.isfinite(out).all()
        assert isinstance(model.predict(np.zeros((history, 5))), float)
    with pytest.raises(ValueError, match="history length"):
        build_feasibility_model(5, FeasibilityConfig(history=4, max_history=8, **SMALL))(torch.randn(2, 9, 5))
    with pytest.raises(ValueError, match=r"\(batch, steps, 5\)"):
        build_feasibility_model(5, FeasibilityConfig(history=4, **SMALL))(torch.randn(2, 4, 6))


def test_history_zero_or_not_temporal_is_the_last_state_mlp():
    for config in (FeasibilityConfig(history=0, **SMALL), FeasibilityConfig(history=10, temporal=False, **SMALL)):
        assert not config.uses_attention and config.input_length == 1
        model = build_feasibility_model(4, config).eval()
        assert isinstance(model, MlpFeasibility)
        history = torch.randn(3, 6, 4)
        changed = history.clone()
        changed[:, :-1] += 5.0  # Only the last observation matters.
        assert torch.allclose(model(history), model(changed))


@pytest.mark.parametrize("pooling", ["last", "mean"])
def test_padding_mask_hides_padded_steps(pooling):
    torch.manual_seed(0)
    model = build_feasibility_model(4, FeasibilityConfig(history=6, pooling=pooling, **SMALL)).eval()
    history = torch.randn(2, 6, 4)
    mask = torch.zeros(2, 6, dtype=torch.bool)
    mask[0, :3] = True  # Entry 0 has 3 real steps.
    garbage = history.clone()
    garbage[0, :3] = 100.0
    masked, masked_garbage = model(history, mask), model(garbage, mask)
    assert torch.allclose(masked, masked_garbage, atol=1e-5)
    assert not torch.allclose(model(history), model(garbage))  # Without the mask the padded steps are read.
    assert torch.allclose(masked[1], model(history[1:], mask[1:])[0], atol=1e-5)
    with pytest.raises(ValueError, match="last step"):
        model(history, torch.ones(2, 6, dtype=torch.bool))


def test_pad_history_left_pads_with_the_first_observation():
    observations = np.arange(6, dtype=np.float32).reshape(3, 2)
    padded = pad_history(observations, 5)
    np.testing.assert_array_equal(padded, [[0, 1], [0, 1], [0, 1], [2, 3], [4, 5]])
    np.testing.assert_array_equal(pad_history(observations, 2), observations[1:])
    assert pad_history(np.zeros((4, 3, 2)), 5).shape == (4, 5, 2)
    with pytest.raises(ValueError):
        pad_history(np.zeros((0, 2)), 3)


def test_overfits_a_nonlinear_function_of_the_last_velocity():
    histories, velocity = velocity_dataset(64, history=5, seed=1)
    returns = np.sin(4.0 * velocity) + velocity ** 2
    config = FeasibilityConfig(history=5, epochs=250, val_fraction=0.0, batch_size=16, **{
        k: v for k, v in SMALL.items() if k != "batch_size"})
    model, metrics = train_feasibility(histories, returns, config)
    assert metrics["n_val"] == 0 and metrics["train_mse"] < 0.05, metrics
    predicted = model.predict(histories)
    assert np.mean((predicted - returns) ** 2) < 0.05 * np.var(returns)


def test_temporal_model_beats_the_last_state_mlp_on_velocity():
    histories, velocity = velocity_dataset(1024, history=4, seed=0)
    results = {}
    for temporal in (True, False):
        config = FeasibilityConfig(history=4, temporal=temporal, epochs=60, **SMALL)
        _, results[temporal] = train_feasibility(histories, velocity, config)
    assert results[True]["val_r2"] > 0.8, results
    assert results[False]["val_r2"] < 0.25, results
    assert results[True]["val_mse"] < 0.5 * results[False]["val_mse"]


def test_training_is_deterministic_for_a_seed_and_keeps_global_rng():
    histories, velocity = velocity_dataset(40, history=3, seed=2)
    config = FeasibilityConfig(history=3, epochs=3, dropout=0.1, **{k: v for k, v in SMALL.items() if k != "dropout"})
    torch.manual_seed(123)
    before = torch.rand(1)
    torch.manual_seed(123)
    first, metrics_a = train_feasibility(histories, velocity, config)
    assert torch.equal(torch.rand(1), before)  # Training did not consume the global generator.
    second, metrics_b = train_feasibility(histories, velocity, config)
    assert metrics_a == metrics_b
    for (name, a), (_, b) in zip(first.state_dict().items(), second.state_dict().items(), strict=True):
        assert torch.equal(a, b), name
    third, _ = train_feasibility(histories, velocity, FeasibilityConfig(
        history=3, epochs=3, seed=1, **{k: v for k, v in SMALL.items()}))
    assert not torch.equal(first.head[0].weight, third.head[0].weight)


def test_model_predicts_in_return_units():
    histories, velocity = velocity_dataset(200, history=3, seed=3)
    returns = 1000.0 + 50.0 * velocity
    model, metrics = train_feasibility(histories, returns, FeasibilityConfig(history=3, epochs=40, **SMALL))
    assert float(model.return_mean) == pytest.approx(1000.0, rel=0.01)
    assert abs(np.mean(model.predict(histories)) - 1000.0) < 5.0
    assert metrics["val_rmse"] == pytest.approx(np.sqrt(metrics["val_mse"]) * float(model.return_std))


def test_threshold_and_score():
    returns = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 100.0, -50.0])
    successes = np.array([True, True, True, True, True, False, False])
    assert feasibility_threshold(returns, successes, quantile=0.0) == 1.0
    assert feasibility_threshold(returns, successes, quantile=0.5) == 3.0
    assert feasibility_threshold(returns, successes) == pytest.approx(1.4)
    with pytest.raises(ValueError, match="no successful"):
        feasibility_threshold(returns, np.zeros(7, bool))
    with pytest.raises(ValueError, match="not positive"):
        feasibility_threshold([-1.0, 2.0], [True, True], quantile=0.0)

    histories, velocity = velocity_dataset(100, history=3, seed=4)
    model, _ = train_feasibility(histories, 10.0 + velocity, FeasibilityConfig(history=3, epochs=5, **SMALL))
    value = model.predict(histories[0])
    assert score(model, histories[0], 2.0) == pytest.approx(value / 2.0)
    assert score(model, histories[:5], 2.0).shape == (5,)
    assert score(model, histories[0, -1:], 2.0) == pytest.approx(model.predict(np.repeat(histories[0, -1:], 3, 0)) / 2)
    with pytest.raises(ValueError):
        score(model, histories[0], 0.0)


def test_save_load_round_trip_and_spec_mismatch(tmp_path):
    histories, velocity = velocity_dataset(60, history=4, seed=5)
    config = FeasibilityConfig(history=4, epochs=3, **SMALL)
    model, metrics = train_feasibility(histories, velocity, config)
    spec = ObservationSpec(3, "toy: position(3)")
    path = save_feasibility(tmp_path / "f" / "insert.pt", model, config, 0.7, spec, source_task="grasp",
                            target_task="insert", metrics=metrics)
    assert [p.name for p in path.parent.iterdir()] == ["insert.pt"]  # No temporary file left behind.
    loaded = load_feasibility(path, spec, expected_target_task="insert")
    assert (loaded.source_task, loaded.target_task, loaded.threshold) == ("grasp", "insert", 0.7)
    assert loaded.config == config and loaded.obs_spec == spec and loaded.config.history == 4
    assert loaded.metrics["train_mse"] == pytest.approx(metrics["train_mse"])
    np.testing.assert_allclose(loaded.model.predict(histories), model.predict(histories), rtol=1e-6)

    other = ObservationSpec(3, "toy: velocity(3)")
    with pytest.raises(ValueError) as error:
        load_feasibility(path, other)
    assert "toy: position(3)" in str(error.value) and "toy: velocity(3)" in str(error.value)
    with pytest.raises(ValueError, match="'insert'.*'orient'"):
        load_feasibility(path, expected_target_task="orient")
    with pytest.raises(ValueError, match="reads 3-dim"):
        save_feasibility(tmp_path / "bad.pt", model, config, 0.7, ObservationSpec(4, "x"), source_task="a",
                         target_task="b")
    with pytest.raises(FileNotFoundError):
        load_feasibility(tmp_path / "missing.pt")

    mlp_config = FeasibilityConfig(history=0, epochs=2, **SMALL)
    mlp, _ = train_feasibility(histories, velocity, mlp_config)
    save_feasibility(tmp_path / "mlp.pt", mlp, mlp_config, 1.0, spec, source_task="grasp", target_task="insert")
    assert isinstance(load_feasibility(tmp_path / "mlp.pt").model, MlpFeasibility)
