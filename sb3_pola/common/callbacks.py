"""Callbacks for offline algorithms: evaluation that reports the D4RL normalised score."""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import EvalCallback

from sb3_pola.common.datasets import normalized_score


class NormalizedScoreEvalCallback(EvalCallback):
    """SB3's ``EvalCallback`` that also logs the normalised score ``100 (R - ref_min) / (ref_max - ref_min)``.

    Next to ``eval/mean_reward`` it records ``eval/normalized_score`` (of the mean return) and
    ``eval/normalized_score_std`` (over episodes) in the same logger dump, keeps
    ``last_normalized_score``, and adds a ``normalized_scores`` array (``[n_evals, n_episodes]``,
    the shape of ``results``) to ``evaluations.npz``, so that ``rl_zoo3.plots.all_plots -k
    normalized_scores`` plots it. Reference scores come from ``ref_scores`` or else from the
    model's ``normalized_score`` (POLA reads them from its dataset); without either it behaves
    exactly like ``EvalCallback``.

    Episode returns are collected in ``_log_success_callback``, the per-step hook that
    ``evaluate_policy`` calls, because ``EvalCallback`` dumps the logger inside ``_on_step``:
    recording after it would put the score in a later row.

    :param args: positional arguments of ``EvalCallback`` (``eval_env`` first)
    :param ref_scores: ``(ref_min, ref_max)``; ``None`` asks the model
    :param kwargs: keyword arguments of ``EvalCallback``
    """

    def __init__(self, *args: Any, ref_scores: tuple[float, float] | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.ref_scores = ref_scores
        self.last_normalized_score: float | None = None
        self.evaluations_normalized: list[list[float]] = []
        self._episode_returns: list[float] = []

    def _normalize(self, returns: float | np.ndarray) -> float | None:
        if self.ref_scores is not None:
            return normalized_score(returns, *self.ref_scores)
        score_fn = getattr(self.model, "normalized_score", None)
        return None if score_fn is None else score_fn(returns)

    def _episode_scores(self) -> list[float] | None:
        """Normalised score of each episode of the current evaluation, or None without reference scores."""
        scores = [self._normalize(r) for r in self._episode_returns]
        return None if not scores or any(s is None for s in scores) else [float(s) for s in scores]  # type: ignore[arg-type]

    def _log_success_callback(self, locals_: dict[str, Any], globals_: dict[str, Any]) -> None:
        super()._log_success_callback(locals_, globals_)
        if not locals_["done"]:
            return
        info = locals_["info"]
        if locals_.get("is_monitor_wrapped", False):
            if "episode" not in info:  # not a real episode end (e.g. Atari life loss): evaluate_policy skips it too
                return
            episode_return = float(info["episode"]["r"])
        else:
            episode_return = float(locals_["current_rewards"][locals_["i"]])
        self._episode_returns.append(episode_return)
        # recorded after every episode: the value standing at the dump covers all episodes of this evaluation
        scores = self._episode_scores()
        if scores is not None:
            self.logger.record("eval/normalized_score", float(np.mean(scores)))  # mean of scores = score of the mean
            self.logger.record("eval/normalized_score_std", float(np.std(scores)))

    def _on_step(self) -> bool:
        evaluating = self.eval_freq > 0 and self.n_calls % self.eval_freq == 0
        if evaluating:
            self._episode_returns = []
        continue_training = super()._on_step()
        scores = self._episode_scores() if evaluating else None
        if scores is not None:
            self.last_normalized_score = float(np.mean(scores))
            self.evaluations_normalized.append(scores)
            if self.verbose >= 1:
                print(f"Normalized score: {self.last_normalized_score:.2f} +/- {np.std(scores):.2f}")
            self._save_normalized()
        return continue_training

    def _save_normalized(self) -> None:
        """Rewrite ``evaluations.npz`` with the normalised scores next to EvalCallback's arrays."""
        if self.log_path is None or len(self.evaluations_normalized) != len(self.evaluations_results):
            return
        extra: dict[str, Any] = {"successes": self.evaluations_successes} if len(self.evaluations_successes) > 0 else {}
        np.savez(
            self.log_path,
            timesteps=self.evaluations_timesteps,
            results=self.evaluations_results,
            ep_lengths=self.evaluations_length,
            normalized_scores=self.evaluations_normalized,
            **extra,
        )


__all__ = ["NormalizedScoreEvalCallback"]
