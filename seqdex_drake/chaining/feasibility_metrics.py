"""Quality measures of a feasibility function: how well its predictions order and explain its labels."""

import numpy as np


def roc_auc(scores, labels) -> float:
    """The area under the ROC curve of ``scores`` for boolean ``labels``: the probability that a random positive
    scores above a random negative, ties counting one half (the Mann-Whitney statistic, from average ranks).
    NaN when ``labels`` lacks positives or negatives."""
    scores = np.asarray(scores, dtype=np.float64).reshape(-1)
    labels = np.asarray(labels, dtype=bool).reshape(-1)
    if scores.shape != labels.shape:
        raise ValueError(f"scores {scores.shape} and labels {labels.shape} differ in shape")
    positives, negatives = int(labels.sum()), int((~labels).sum())
    if positives == 0 or negatives == 0:
        return float("nan")
    order = np.argsort(scores, kind="stable")
    ranks = np.empty(len(scores))
    sorted_scores = scores[order]
    start = 0
    while start < len(scores):  # Average ranks (1-based) over runs of tied scores.
        end = start
        while end + 1 < len(scores) and sorted_scores[end + 1] == sorted_scores[start]:
            end += 1
        ranks[order[start:end + 1]] = 0.5 * (start + end) + 1.0
        start = end + 1
    return float((ranks[labels].sum() - positives * (positives + 1) / 2) / (positives * negatives))


def r_squared(mse: float, variance: float) -> float:
    """1 - mse / variance: the share of the targets' variance a prediction explains; NaN where the targets hardly
    vary (variance <= 1e-12: a split of one outcome only), where R^2 says nothing."""
    return 1.0 - mse / variance if variance > 1e-12 else float("nan")
