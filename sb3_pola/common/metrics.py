"""The D4RL normalised score, ``100 (R - ref_min) / (ref_max - ref_min)``, and the success rate: the one implementation.

This module imports only NumPy and the standard library: the d3rlpy baselines' worker
(:mod:`sb3_pola.grid.peers_worker`) runs in a virtual environment without ``sb3_pola`` and
loads this file by its path.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

# the columns of one evaluation row: the score grid's scores.csv and the d3rlpy baselines' peers.csv
EVALUATION_FIELDS = [
    "dataset",
    "variant",
    "seed",
    "step",
    "score",
    "score_std",
    "mean_return",
    "eval_episodes",
    "wall_s",
    "success",
]

_warned_no_ref: set[str] = set()


def has_reference_scores(ref_min: float | None, ref_max: float | None) -> bool:
    """Whether the reference returns define a score: both known and different.

    :param ref_min: return of a random policy
    :param ref_max: return of an expert policy
    """
    return ref_min is not None and ref_max is not None and ref_max != ref_min


def normalized_scores(
    returns: float | Sequence[float] | np.ndarray, ref_min: float | None, ref_max: float | None
) -> np.ndarray:
    """The D4RL score of each return, float64 of the shape of ``returns`` (NaN without usable reference scores).

    :param returns: one return or several
    :param ref_min: return of a random policy
    :param ref_max: return of an expert policy
    :return: ``100 (R - ref_min) / (ref_max - ref_min)`` per return
    """
    values = np.asarray(returns, dtype=np.float64)
    if not has_reference_scores(ref_min, ref_max):
        return np.full(values.shape, np.nan)
    assert ref_min is not None and ref_max is not None
    return 100.0 * (values - ref_min) / (ref_max - ref_min)


def normalized_score(
    returns: float | Sequence[float] | np.ndarray, ref_min: float | None, ref_max: float | None, source: str = ""
) -> float | None:
    """The D4RL score of the mean return (equal to the mean of the scores: the score is affine in the return).

    :param returns: one return or several (their mean is scored)
    :param ref_min: return of a random policy
    :param ref_max: return of an expert policy
    :param source: whose reference scores these are, for the warning (e.g. ``"Dataset 'hopper/medium-v0'"``)
    :return: the score, or ``None`` (with a warning, once per source and reference scores) when they are missing
    """
    if not has_reference_scores(ref_min, ref_max):
        key = f"{source}|{ref_min}|{ref_max}"
        if key not in _warned_no_ref:
            _warned_no_ref.add(key)
            warnings.warn(
                f"{source or 'Scoring'}: no reference scores to normalise with (ref_min_score={ref_min}, "
                f"ref_max_score={ref_max}): the normalised score is None"
            )
        return None
    mean_return = float(np.mean(np.asarray(returns, dtype=np.float64)))
    return float(normalized_scores(mean_return, ref_min, ref_max))


# the step-info keys goal-reaching envs report success under (Gymnasium-Robotics' mazes: "success")
SUCCESS_KEYS = ("success", "is_success")


def update_success(success: bool | None, info: Mapping[str, Any]) -> bool | None:
    """An episode's success after one more step: true once a step's info reports it, ``None`` while none reports any.

    :param success: the episode's success so far (``None`` at its start)
    :param info: the step's info dict
    """
    for key in SUCCESS_KEYS:
        if key in info:
            success = bool(success) or bool(info[key])
    return success


def success_rate(successes: Iterable[bool | None]) -> float | None:
    """The fraction of successful episodes among those that report success (``None`` if none does)."""
    reported = [float(s) for s in successes if s is not None]
    return float(np.mean(reported)) if reported else None


def evaluation_seed(seed: int) -> int:
    """The reset seed of the first episode of every evaluation of a run of ``seed`` (episode ``i``: ``+ i``): the score
    grid's and the d3rlpy baselines' protocol, so that both meet the same starts."""
    return 10_000 * (seed + 1)


__all__ = [
    "EVALUATION_FIELDS",
    "SUCCESS_KEYS",
    "evaluation_seed",
    "has_reference_scores",
    "normalized_score",
    "normalized_scores",
    "success_rate",
    "update_success",
]
