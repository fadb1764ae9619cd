"""One cell of the score grid: train a (dataset, variant, seed) model, evaluate it every ``eval_freq`` steps, checkpoint
it, and resume it from its checkpoint (in a folder, or in a workspace synchronised with an fsspec URL).
"""

from __future__ import annotations

import json
import math
import pathlib
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import CSVOutputFormat, Logger

from sb3_pola.common.checkpoint import load_module_state, load_or_make, save_checkpoint, save_module_state
from sb3_pola.common.datasets import make_env
from sb3_pola.common.evaluation import evaluate
from sb3_pola.common.metrics import evaluation_seed, success_rate
from sb3_pola.grid.rows import append_row, cell_name, read_rows, rows_rel, slug, write_rows
from sb3_pola.grid.variants import VARIANTS, Config, apply_eval_rule, pola_kwargs
from sb3_pola.pola import POLA

if TYPE_CHECKING:
    from sb3_pola.grid.storage import Workspace


def evaluation_scores(model: Any, env: Any, n_episodes: int, seed: int, deterministic: bool = True) -> dict[str, Any]:
    """The CSV columns of one evaluation of a cell's model (the resets of seed ``seed``'s protocol)."""
    successes: list[bool | None] = []
    returns = evaluate(model, env, n_episodes, seed=evaluation_seed(seed), deterministic=deterministic, successes=successes)
    scores = np.array([_nan_if_none(model.normalized_score(r)) for r in returns], dtype=float)
    rate = success_rate(successes)
    return {
        "score": round(float(np.mean(scores)), 3),
        "score_std": round(float(np.std(scores)), 3),
        "mean_return": round(float(np.mean(returns)), 2),
        "eval_episodes": n_episodes,
        "success": math.nan if rate is None else round(rate, 3),
    }


def _nan_if_none(value: float | None) -> float:
    return math.nan if value is None else float(value)


def _train_logger(folder: pathlib.Path, done_steps: int) -> Any:
    """An SB3 logger writing ``train/*`` statistics to ``folder/progress_from<step>.csv`` (a file per resumed segment)."""
    folder.mkdir(parents=True, exist_ok=True)
    return Logger(folder=str(folder), output_formats=[CSVOutputFormat(str(folder / f"progress_from{done_steps}.csv"))])


def dynamics_path(out: pathlib.Path, dataset: str, seed: int, config: Config) -> pathlib.Path:
    """Where a cell's fitted dynamics model is kept: one per dataset with ``share_dynamics``, else one per (dataset, seed)."""
    dyn_seed = "shared" if config.share_dynamics else f"seed{seed}"
    return out / "dynamics" / f"{slug(dataset)}__{dyn_seed}.pt"


def new_cell_model(variant: str, seed: int, config: Config, dataset: str, device: str) -> Any:
    """A fresh POLA model of a cell: the variant's arguments over the config's.

    :param variant: a key of :data:`VARIANTS`
    :param seed: random seed
    :param config: budget and hyperparameters
    :param dataset: Minari dataset id
    :param device: torch device
    :return: the model
    """
    _, kwargs, policy_kwargs = VARIANTS[variant]
    extra = pola_kwargs({**config.extra, **kwargs})
    # the policy's arguments: the configuration's, then --extra's (JSON values, e.g. time_embedding_dim), then the variant's
    policy_kwargs = {
        "net_arch": config.net_arch,
        "n_action_samples": config.n_action_samples,
        **extra.pop("policy_kwargs", {}),
        **policy_kwargs,
    }
    return POLA(
        "MlpPolicy",
        dataset=dataset,
        batch_size=config.batch_size,
        n_critics=config.n_critics,
        top_k=config.top_k,
        dynamics_kwargs=config.dynamics_kwargs,
        dynamics_fit_kwargs=config.dynamics_fit_kwargs,
        policy_kwargs=policy_kwargs,
        seed=seed,
        device=device,
        **extra,
    )


def run_cell(
    dataset: str,
    variant: str,
    seed: int,
    config: Config,
    out: pathlib.Path,
    device: str,
    verbose: int = 1,
    rows_csv: pathlib.Path | None = None,
    stop_after_dynamics: bool = False,
    on_save: Callable[[], None] = lambda: None,
) -> bool:
    """Train and evaluate one (dataset, variant, seed) cell, resuming from its checkpoint if there is one.

    Checkpoints carry the RNG states (:func:`~sb3_pola.common.checkpoint.save_checkpoint`), so on CPU a
    resumed cell ends with the scores of an uninterrupted one.

    :param dataset: Minari dataset id
    :param variant: a key of :data:`VARIANTS`
    :param seed: random seed of the model (and of the evaluation resets)
    :param config: budget and hyperparameters
    :param out: output folder
    :param device: torch device
    :param verbose: 0 silent, 1 a line per evaluation
    :param rows_csv: where this cell's evaluation rows go (``out/scores.csv`` if ``None``)
    :param stop_after_dynamics: stop (with a checkpoint) after the first gradient step once the dynamics model
        is fitted and saved, so that other cells can share it while this one continues later
    :param on_save: called after every checkpoint (its rows are written first), e.g. to upload the cell's files
        (:func:`run_stored_cell`)
    :return: whether the cell finished (its marker is written)
    """
    name = cell_name(dataset, variant, seed)
    csv_path, ckpt = rows_csv or out / "scores.csv", out / "ckpt" / f"{name}.zip"
    ckpt.parent.mkdir(parents=True, exist_ok=True)
    dyn_path = dynamics_path(out, dataset, seed, config)
    dyn_path.parent.mkdir(parents=True, exist_ok=True)

    def make_model() -> POLA:
        model = new_cell_model(variant, seed, config, dataset, device)
        dynamics = model.policy.dynamics
        if dynamics is not None and dyn_path.exists():  # fitted by another cell of this dataset
            load_module_state(dynamics, dyn_path, device)
            dynamics.freeze()
            model.policy.dynamics_fitted.fill_(True)
        return model

    model = cast(POLA, load_or_make(POLA, ckpt, make_model, dataset=dataset, device=device))
    done_steps = model.num_timesteps
    previous_wall = 0.0
    if done_steps > 0:
        rows = [r for r in read_rows(csv_path) if (r["dataset"], r["variant"], r["seed"]) == (dataset, variant, seed)]
        previous_wall = max((r["wall_s"] for r in rows if r["step"] <= done_steps), default=0.0)
        if verbose:
            print(f"[score] {name}: resuming from step {done_steps}")
    # drop evaluations made after the checkpoint (an interruption between an evaluation and its checkpoint)
    all_rows = read_rows(csv_path)
    kept = [
        r for r in all_rows if (r["dataset"], r["variant"], r["seed"]) != (dataset, variant, seed) or r["step"] <= done_steps
    ]
    if len(kept) != len(all_rows):
        write_rows(csv_path, kept)
    remaining = config.steps - done_steps
    # the default keeps the variant's actor and the config's n_action_samples; another rule sets both
    deterministic = True if config.eval_rule == "ema" else apply_eval_rule(model, config.eval_rule)
    env = make_env(model.offline_data if model.offline_data is not None else dataset)
    start = time.perf_counter()

    class ScoreCallback(BaseCallback):
        """Saves the fitted dynamics model once; evaluates, logs a CSV row and checkpoints every ``eval_freq`` steps."""

        def _on_step(self) -> bool:
            dynamics = model.policy.dynamics
            if dynamics is not None and not dyn_path.exists() and bool(model.policy.dynamics_fitted):
                save_module_state(dynamics, dyn_path)
            step = model.num_timesteps
            if step % config.eval_freq == 0 or step == config.steps:
                row = {
                    "dataset": dataset,
                    "variant": variant,
                    "seed": seed,
                    "step": step,
                    **evaluation_scores(model, env, config.eval_episodes, seed, deterministic=deterministic),
                    "wall_s": round(previous_wall + time.perf_counter() - start, 1),
                }
                append_row(csv_path, row)
                save_checkpoint(model, ckpt)
                on_save()
                if verbose:
                    print(
                        f"[score] {name} step {step}: score {row['score']:.1f} "
                        f"(return {row['mean_return']:.0f}), {row['wall_s']:.0f}s"
                    )
                    sys.stdout.flush()
            elif stop_after_dynamics:
                save_checkpoint(model, ckpt)
                on_save()
            return not stop_after_dynamics

    if remaining > 0:
        model.set_logger(_train_logger(out / "train" / name, done_steps))
        model.learn(remaining, callback=ScoreCallback(), reset_num_timesteps=done_steps == 0, log_interval=config.log_interval)
    env.close()
    if stop_after_dynamics and model.num_timesteps < config.steps:
        return False
    marker = out / "cells" / f"{name}.json"
    marker.parent.mkdir(parents=True, exist_ok=True)
    info = {"dataset": dataset, "variant": variant, "seed": seed, "steps": config.steps, "signature": config.signature()}
    info["wall_s"] = round(previous_wall + time.perf_counter() - start, 1)
    info["dynamics_fit"] = {k: float(v) for k, v in getattr(model, "dynamics_fit_info", {}).items()}
    models = out / "models"
    models.mkdir(exist_ok=True)
    if ckpt.exists():  # the last evaluation's checkpoint is the final model; keep it for diagnosis and re-evaluation
        ckpt.replace(models / f"{name}.zip")
    marker.write_text(json.dumps(info, indent=1))
    return True


def run_stored_cell(
    view: Workspace,
    dataset: str,
    variant: str,
    seed: int,
    config: Config,
    device: str,
    verbose: int = 1,
    stop_after_dynamics: bool = False,
) -> bool:
    """:func:`run_cell` in a workspace, its rows in ``rows/<cell>.csv``: its files pulled first, pushed at every checkpoint.

    With a scratch workspace (an fsspec URL) the cell pulls its checkpoint, rows, dynamics model and training
    statistics, uploads the changed ones after every evaluation (the rows before the checkpoint, so that no
    checkpoint is ever ahead of its rows) and at the end its final model, then its marker, then deletes its
    checkpoint: a kill at any point leaves the storage resumable.

    :param view: the workspace of the output (:func:`~sb3_pola.grid.storage.open_workspace`)
    :param dataset: Minari dataset id
    :param variant: a key of :data:`VARIANTS`
    :param seed: random seed
    :param config: budget and hyperparameters
    :param device: torch device
    :param verbose: 0 silent, 1 a line per evaluation
    :param stop_after_dynamics: see :func:`run_cell`
    :return: whether the cell finished
    """
    name = cell_name(dataset, variant, seed)
    rows, ckpt, train = rows_rel(dataset, variant, seed), f"ckpt/{name}.zip", f"train/{name}"
    dyn = dynamics_path(view.folder, dataset, seed, config)
    view.pull(rows, ckpt, dyn)
    view.pull_tree(train)

    def save() -> None:
        view.push(rows, dyn, ckpt)
        view.push_tree(train)

    rows_csv = view.folder / rows
    rows_csv.parent.mkdir(parents=True, exist_ok=True)
    finished = run_cell(
        dataset, variant, seed, config, view.folder, device, verbose, rows_csv, stop_after_dynamics, on_save=save
    )
    save()
    if finished:
        view.push(f"models/{name}.zip", f"cells/{name}.json")
        view.remove(ckpt)
    return finished
