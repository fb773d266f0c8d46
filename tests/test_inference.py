"""The numpy inference snapshots (``controller/inference.py``) against the torch models they copy: the actor MLP with
its observation normalizer, the attention feasibility model (pooling, positional tables, padding, pre- and
post-norm layers) and the no-history MLP F, on random weights and inputs; staleness after in-place weight
changes; and the Drake systems' numpy and torch paths giving the same outputs."""

import types

import numpy as np
import pytest
import torch

from seqdex_drake.chaining.feasibility import FeasibilityConfig, MlpFeasibility, build_feasibility_model
from seqdex_drake.controller.inference import (
    FeasibilityBank,
    FeasibilitySnapshot,
    PolicySnapshot,
    limit_blas_threads,
    snapshot_feasibility,
)
from seqdex_drake.controller.policy import PolicyParams, PolicySystem
from seqdex_drake.controller.switcher import FeasibilitySwitcher, SwitcherParams, feasibility_score
from seqdex_drake.rl.networks import ActorCritic

RTOL = 1e-5


def assert_close(actual, expected, rtol=RTOL):
    """Equal to ``rtol`` relative to the largest magnitude of ``expected`` (entries near 0 are not singled out)."""
    expected = np.asarray(expected, dtype=np.float64)
    np.testing.assert_allclose(actual, expected, rtol=rtol, atol=rtol * max(np.abs(expected).max(), 1e-30))


def random_actor(obs_dim=37, hidden=(64, 48), activation="elu", normalize=True, seed=0) -> ActorCritic:
    """An actor with random weights and biases, a fitted normalizer (some inputs clip) and a large output."""
    torch.manual_seed(seed)
    model = ActorCritic(obs_dim, 19, hidden, (8,), activation=activation, normalize_observations=normalize)
    model.update_normalizer(torch.randn(256, obs_dim) * torch.linspace(0.1, 4, obs_dim) + 2)
    with torch.no_grad():
        for layer in model.actor:
            if isinstance(layer, torch.nn.Linear):
                layer.bias.normal_(0, 0.3)
        model.actor[-1].weight.mul_(30.0)
    return model.eval()


def torch_action(model: ActorCritic, observations: np.ndarray) -> np.ndarray:
    with torch.inference_mode():
        return model.action_mean(torch.as_tensor(np.asarray(observations, dtype=np.float32))).numpy()


@pytest.mark.parametrize("activation", ["elu", "relu", "tanh", "selu"])
@pytest.mark.parametrize("normalize", [True, False])
def test_policy_snapshot_equals_torch_action_mean(activation, normalize):
    model = random_actor(activation=activation, normalize=normalize)
    rng = np.random.default_rng(1)
    observations = rng.normal(size=(8, 37)) * 6 + 2  # Some normalized entries exceed the clip of 5.
    snapshot = PolicySnapshot(model)
    expected = torch_action(model, observations)
    assert np.abs(expected).max() > 0.5  # Not the near-zero actions of a fresh output layer.
    for single, reference in zip(observations, expected, strict=True):
        assert_close(snapshot(single), reference)
    assert_close(snapshot(observations), expected)
    assert_close(PolicySnapshot(model, dtype=np.float64)(observations), expected)
    with pytest.raises(ValueError, match="37 entries"):
        snapshot(np.zeros(36))


def test_policy_snapshot_keeps_fixed_action_dims():
    model = random_actor()
    fixed = np.full(19, np.nan, dtype=np.float32)
    fixed[:16] = np.linspace(-0.5, 0.5, 16)
    with torch.no_grad():
        model.action_fixed.copy_(torch.as_tensor(fixed))
    observations = np.random.default_rng(2).normal(size=(3, 37))
    assert_close(PolicySnapshot(model)(observations), torch_action(model, observations))


def test_policy_snapshot_paper_size():
    torch.manual_seed(3)
    model = ActorCritic(159, 19, (1024, 1024, 512), (8,))
    model.update_normalizer(torch.randn(64, 159) * 3 + 1)
    observation = np.random.default_rng(3).normal(size=159)
    assert_close(PolicySnapshot(model)(observation), torch_action(model, observation[None])[0])


def feasibility_model(obs_dim=23, seed=0, **config) -> torch.nn.Module:
    """An F with random weights and fitted normalizers (some inputs clip), in eval mode."""
    config = FeasibilityConfig(**{"history": 6, "d_model": 32, "heads": 4, "layers": 2, "feedforward": 48,
                                  "seed": seed, **config})
    torch.manual_seed(seed)
    model = build_feasibility_model(obs_dim, config)
    model.fit_normalizers(torch.randn(40, 6, obs_dim) * 2 + 1, torch.randn(40) * 7 + 3)
    with torch.no_grad():
        for name, parameter in model.named_parameters():
            if name.endswith("bias") or "norm" in name:
                parameter.add_(torch.randn_like(parameter) * 0.2)  # Non-trivial LayerNorm affine parts.
    return model.eval()


@pytest.mark.parametrize("config", [
    {},
    {"pooling": "mean"},
    {"positional": "sinusoidal", "layers": 3},
    {"heads": 1, "layers": 1},
    {"history": 10, "d_model": 128, "heads": 4, "feedforward": 256},  # The paper-size default.
])
def test_temporal_feasibility_snapshot_equals_torch(config):
    model = feasibility_model(**config)
    snapshot = FeasibilitySnapshot(model)
    assert snapshot.temporal and snapshot.input_length == model.config.history
    rng = np.random.default_rng(2)
    for steps in (1, 3, model.config.history, model.config.history + 4):  # padded, exact and cut histories
        history = rng.normal(size=(steps, 23)) * 4
        expected = model.predict(history)
        assert snapshot(history) == pytest.approx(expected, rel=RTOL, abs=RTOL * abs(expected) + 1e-6)
    batch = rng.normal(size=(5, model.config.history, 23)) * 4
    assert_close(snapshot(batch), model.predict(batch))
    assert_close(FeasibilitySnapshot(model, dtype=np.float64)(batch), model.predict(batch))


def test_post_norm_encoder_layers():
    model = feasibility_model(layers=2)
    for layer in model.encoder.layers:
        layer.norm_first = False  # torch's layer reads the flag at run time
    batch = np.random.default_rng(4).normal(size=(3, 6, 23))
    assert_close(FeasibilitySnapshot(model)(batch), model.predict(batch))


@pytest.mark.parametrize("config", [{"temporal": False}, {"history": 0}])
def test_mlp_feasibility_snapshot_equals_torch(config):
    model = feasibility_model(**config)
    assert isinstance(model, MlpFeasibility)
    snapshot = FeasibilitySnapshot(model)
    assert not snapshot.temporal and snapshot.input_length == 1
    history = np.random.default_rng(5).normal(size=(4, 23)) * 3
    assert snapshot(history) == pytest.approx(model.predict(history), rel=RTOL)
    batch = np.random.default_rng(6).normal(size=(7, 2, 23)) * 3
    assert_close(snapshot(batch), model.predict(batch))


def test_snapshots_leave_the_models_alone():
    for model in (feasibility_model(), feasibility_model(positional="sinusoidal"), random_actor()):
        before = {name: value.clone() for name, value in model.state_dict().items()}
        (PolicySnapshot if isinstance(model, ActorCritic) else FeasibilitySnapshot)(model)
        for layer in getattr(getattr(model, "encoder", None), "layers", []):
            layer.norm_first = False
        if not isinstance(model, ActorCritic):
            FeasibilitySnapshot(model)  # post-norm layers keep their own LayerNorm arrays
        for name, value in model.state_dict().items():
            assert torch.allclose(value, before[name], rtol=0, atol=0, equal_nan=True), name


def test_bank_stacks_same_architecture_models_and_equals_each_model():
    models = [feasibility_model(obs_dim=23, seed=1), feasibility_model(obs_dim=19, seed=2),
              feasibility_model(obs_dim=23, seed=3, pooling="mean"), feasibility_model(obs_dim=30, seed=4),
              feasibility_model(obs_dim=23, seed=5, temporal=False)]
    bank = FeasibilityBank(models)
    assert sorted(len(members) for members, _ in bank.groups) == [1, 1, 3]  # 23, 19 and 30 inputs stack
    rng = np.random.default_rng(9)
    for steps in (1, 4, 6, 8):
        histories = [rng.normal(size=(steps, model.obs_dim)) * 3 for model in models]
        expected = np.array([model.predict(history) for model, history in zip(models, histories, strict=True)])
        assert_close(bank(histories), expected)
        for value, reference in zip(bank(histories), expected, strict=True):
            assert value == pytest.approx(reference, rel=RTOL, abs=1e-6)
    assert not bank.stale()
    with torch.no_grad():
        models[1].embed.weight.mul_(1.5)
    assert bank.stale()
    with pytest.raises(ValueError, match="one history per model"):
        bank(histories[:2])


def test_snapshots_notice_in_place_weight_changes():
    model = random_actor()
    snapshot = PolicySnapshot(model)
    assert not snapshot.stale()
    with torch.no_grad():
        model.actor[0].weight.mul_(2.0)
    assert snapshot.stale()
    model.update_normalizer(torch.randn(10, 37))
    assert_close(PolicySnapshot(model)(np.ones(37)), torch_action(model, np.ones((1, 37)))[0])
    f = feasibility_model()
    f_snapshot = FeasibilitySnapshot(f)
    f.load_state_dict(feasibility_model(seed=1).state_dict())
    assert f_snapshot.stale()


def test_snapshot_feasibility_falls_back_for_other_models():
    assert snapshot_feasibility(types.SimpleNamespace(predict=lambda history: 0.0)) is None
    assert snapshot_feasibility(feasibility_model().train()) is None  # dropout active: not an inference model
    assert isinstance(snapshot_feasibility(feasibility_model()), FeasibilitySnapshot)


def test_limit_blas_threads_runs():
    assert isinstance(limit_blas_threads(1), bool)
    a = np.random.default_rng(0).normal(size=(3, 300))
    np.testing.assert_allclose(a @ a.T, np.einsum("ij,kj->ik", a, a))


# ------------------------------------------------------------------------------------------ Drake systems
def test_policy_system_numpy_and_torch_paths_agree_and_follow_weight_changes():
    model = random_actor(obs_dim=159)
    fast = PolicySystem(model, 159, PolicyParams(inference="numpy"))
    reference = PolicySystem(model, 159, PolicyParams(inference="torch"))
    rng = np.random.default_rng(7)
    for _ in range(3):
        observation = rng.normal(size=159) * 3
        np.testing.assert_allclose(fast.raw_action(observation), reference.raw_action(observation), atol=2e-5)
        np.testing.assert_allclose(fast.raw_action(observation), fast.torch_raw_action(observation), atol=2e-5)
    with torch.no_grad():
        model.actor[-1].bias.add_(0.5)
    np.testing.assert_allclose(fast.raw_action(observation), reference.raw_action(observation), atol=2e-5)
    with pytest.raises(ValueError, match="inference"):
        PolicySystem(model, 159, PolicyParams(inference="onnx"))


def test_switcher_numpy_scores_equal_torch_scores():
    fs = [None, types.SimpleNamespace(model=feasibility_model(obs_dim=5), threshold=2.0, config=None)]
    fs[1].config = fs[1].model.config
    systems = {path: FeasibilitySwitcher(fs, [5, 5], [100, 100], 0.1, SwitcherParams(inference=path))
               for path in ("numpy", "torch")}
    rng = np.random.default_rng(8)
    for steps in (1, 4, 6, 9):
        history = rng.normal(size=(steps, 5)) * 2
        expected = feasibility_score(fs[1], history)
        assert systems["numpy"].score(1, history) == pytest.approx(expected, rel=RTOL, abs=1e-6)
        assert systems["torch"].score(1, history) == expected
