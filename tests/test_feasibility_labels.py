"""F labelled with success (the release's label) beside the paper's return label: the AUC and R^2 it is judged by,
a success-labelled fit on data whose returns do not order the outcomes, and stratified cross-validation."""

import itertools

import numpy as np
import pytest

from seqdex_drake.chaining.feasibility import (
    SUCCESS_THRESHOLD,
    FeasibilityConfig,
    cross_validate,
    feasibility_targets,
    feasibility_threshold,
    score,
    train_feasibility,
)
from seqdex_drake.chaining.feasibility_metrics import r_squared, roc_auc

SMALL = dict(d_model=32, heads=4, layers=1, feedforward=64, dropout=0.0, mlp_hidden=(64, 64), batch_size=64, lr=1e-3)


def pairwise_auc(scores, labels) -> float:
    """The AUC by its definition: over every (positive, negative) pair, 1 if the positive scores higher, 1/2 on a
    tie."""
    positives = [s for s, y in zip(scores, labels, strict=True) if y]
    negatives = [s for s, y in zip(scores, labels, strict=True) if not y]
    wins = [1.0 if p > n else 0.5 if p == n else 0.0 for p, n in itertools.product(positives, negatives)]
    return float(np.mean(wins))


def test_roc_auc_is_the_pairwise_probability_with_ties():
    rng = np.random.default_rng(3)
    for _ in range(20):
        scores = rng.integers(0, 5, 30).astype(float)  # Many ties.
        labels = rng.random(30) < 0.4
        assert roc_auc(scores, labels) == pytest.approx(pairwise_auc(scores, labels), abs=1e-12)
    assert roc_auc([0.1, 0.2, 0.9], [False, False, True]) == 1.0
    assert roc_auc([0.9, 0.2, 0.1], [False, False, True]) == 0.0
    assert np.isnan(roc_auc([0.1, 0.2], [True, True]))
    with pytest.raises(ValueError, match="differ in shape"):
        roc_auc([0.1, 0.2], [True])


def test_r_squared_is_undefined_without_variance():
    assert r_squared(0.25, 1.0) == 0.75
    assert np.isnan(r_squared(0.0, 0.0)) and np.isnan(r_squared(1e-3, 1e-14))


def outcome_dataset(count: int, seed: int = 0):
    """Histories whose last step's first entry decides success (> 0), and returns that do not order the outcomes:
    successes have large negative returns, failures small positive ones (as Orient's in the pile)."""
    rng = np.random.default_rng(seed)
    histories = rng.normal(0.0, 1.0, (count, 4, 3)).astype(np.float32)
    successes = histories[:, -1, 0] > 0.3
    returns = np.where(successes, -30.0 + rng.normal(0, 20, count), rng.normal(5.0, 1.0, count))
    return histories, returns, successes


def test_success_label_fits_where_returns_cannot_set_h():
    histories, returns, successes = outcome_dataset(300)
    with pytest.raises(ValueError, match="not positive"):
        feasibility_threshold(returns, successes)
    config = FeasibilityConfig(history=4, epochs=60, label="success", **SMALL)
    targets = feasibility_targets(returns, successes, "success")
    assert set(np.unique(targets)) == {0.0, 1.0}
    model, metrics = train_feasibility(histories, targets, config, successes=successes)
    assert metrics["val_auc"] > 0.9 and metrics["train_auc"] > 0.9
    test, _, test_successes = outcome_dataset(200, seed=1)
    c = score(model, test, SUCCESS_THRESHOLD)
    assert np.mean((c > 1.0) == test_successes) > 0.85  # c > 1 means "more likely to succeed than not".
    # The return-labelled F on the same data orders the outcomes backwards.
    _, backwards = train_feasibility(histories, returns, FeasibilityConfig(history=4, epochs=60, **SMALL),
                                     successes=successes)
    assert backwards["val_auc"] < 0.2
    with pytest.raises(ValueError, match="label must be one of"):
        FeasibilityConfig(label="reward")


def test_cross_validation_is_stratified_out_of_fold_and_deterministic():
    histories, returns, successes = outcome_dataset(120)
    config = FeasibilityConfig(history=4, epochs=30, label="success", **SMALL)
    targets = feasibility_targets(returns, successes, "success")
    first = cross_validate(histories, targets, successes, config, folds=4)
    assert first == cross_validate(histories, targets, successes, config, folds=4)
    assert first["cv_n"] == 120 and first["cv_folds"] == 4 and first["cv_auc"] > 0.9
    # Labels that the histories do not predict: out of fold, F can do no better than chance.
    shuffled = np.random.default_rng(7).permutation(successes)
    chance = cross_validate(histories, shuffled.astype(float), shuffled, config, folds=4)
    assert abs(chance["cv_auc"] - 0.5) < 0.2 and chance["cv_r2"] < 0.1
    with pytest.raises(ValueError, match="folds"):
        cross_validate(histories, targets, successes, config, folds=1)
