"""``sb3-pola score``: POLA and its ablations over datasets and seeds, learning curves, a Table-I-style table.

Every (dataset, variant, seed) *cell* trains one POLA model for ``--steps`` gradient steps and
evaluates its EMA policy every ``--eval-freq`` steps on ``--eval-episodes`` episodes of the
dataset's env (D4RL-normalised score from the dataset's reference scores). Outputs, all under
``--out``:

- ``scores.csv``: one row per evaluation (written as it happens);
- ``table.md``: final and best score, mean +- std over seeds, next to the paper's Table I;
- ``fig_rollout_<dataset>.png`` (paper Fig. 3: T in {0, 1, 3, 5}) and
  ``fig_products_<dataset>.png`` (paper Fig. 4: products on/off/in the critic), BC as the floor;
- ``config.json`` (budget, machine, date), ``cells/`` (finished cells), ``ckpt/`` (a checkpoint
  per running cell, saved at every evaluation), ``dynamics/`` (fitted dynamics models),
  ``models/`` (every finished cell's final model) and ``train/<cell>/`` (the training statistics
  of the SB3 logger, ``train/*`` every ``--log-interval`` steps, as CSV: one file per segment of a
  resumed run).

``--out`` is a folder, or an fsspec URL (``s3://bucket/run`` with s3fs installed, ``file:///nfs/run``, ...):
each cell then works in a local scratch folder synchronised with the storage and writes its rows to
``rows/<cell>.csv``, merged into ``scores.csv`` by the driver (:func:`run_stored_cell`,
:mod:`sb3_pola.experiments.storage`).

``--reevaluate RULE ...`` evaluates the saved final models again under other evaluation rules
(``ema``, ``online``, ``stochastic``: one sample of the noisy reverse chain, ``candidates<N>``: N noisy
candidates ranked by the critic, as Diffusion-QL evaluates) and writes ``reeval.csv`` and ``reeval.md``.

An interrupted run is resumed by the same command: finished cells are skipped, a running cell
continues from its last checkpoint. ``--ray [ADDRESS]`` runs the cells as Ray tasks, on this machine or a
cluster (:mod:`sb3_pola.experiments.ray_grid`). Presets: ``cpu`` (light networks, a few thousand steps),
``paper`` (the paper's configuration, for a CUDA GPU), ``auto`` (``paper`` on CUDA, else ``cpu``).
Any preset value can be overridden from the command line.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import hashlib
import json
import math
import os
import pathlib
import platform
import re
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from sb3_pola.common.scores import success_rate, update_success
from sb3_pola.experiments.diagnostics import write_diagnostics
from sb3_pola.pola.pola import PAPER_FORM

if TYPE_CHECKING:
    from sb3_pola.experiments.storage import Workspace

# ----------------------------------------------------------------------------------------- variants

# POLA arguments of the weakened Q term of issue #12 (part of the defaults since 2026-12-02; the paper's form, the
# defaults before, is sb3_pola.PAPER_FORM)
FLOOR_FORM: dict[str, Any] = {"lookahead_normalization": "weights", "q_scale_floor": "auto"}

# name -> (label for legends, POLA keyword arguments, policy_kwargs)
VARIANTS: dict[str, tuple[str, dict[str, Any], dict[str, Any]]] = {
    "T0": ("POLA T=0 (no look-ahead)", {"rollout_length": 0}, {}),
    "T1": ("POLA T=1", {"rollout_length": 1}, {}),
    "T3": ("POLA T=3", {"rollout_length": 3}, {}),
    "T5": ("POLA T=5", {"rollout_length": 5}, {}),
    "T0-noproducts": ("T=0, no products", {"rollout_length": 0, "use_state_products": False}, {}),
    "T3-noproducts": ("T=3, no products", {"rollout_length": 3, "use_state_products": False}, {}),
    "T3-criticproducts": ("T=3, products in actor and critic", {"rollout_length": 3}, {"critic_state_products": True}),
    "BC": ("BC (diffusion actor, eta=0)", {"rollout_length": 0, "eta": 0.0}, {}),
    # the weakened Q term of issue #12: |Q| floored at the dataset's value scale, look-ahead sum / sum gamma^i
    "T0-floor": ("T=0, Q-scale floor", {"rollout_length": 0, **FLOOR_FORM}, {}),
    "T3-floor": ("T=3, Q-scale floor, weights normalised", {"rollout_length": 3, **FLOOR_FORM}, {}),
}
ALL_VARIANTS = list(VARIANTS)
# the variants of each figure (paper Fig. 3 and Fig. 4); BC is drawn in both as the floor
FIGURES: dict[str, list[str]] = {
    "rollout": ["T0", "T1", "T3", "T5", "T3-floor", "BC"],
    "products": ["T3", "T3-noproducts", "T3-criticproducts", "T0", "T0-noproducts", "BC"],
}

# POLA's numbers in the paper's Table I (D4RL MuJoCo v2, mean +- std over 10 replications)
PAPER_TABLE_I: dict[tuple[str, str], str] = {
    ("halfcheetah", "medium-expert"): "111.2 ± 2.4",
    ("halfcheetah", "medium-replay"): "62.1 ± 1.3",
    ("halfcheetah", "medium"): "71.8 ± 0.4",
    ("halfcheetah", "random"): "33.7 ± 1.9",
    ("hopper", "medium-expert"): "111.3 ± 1.7",
    ("hopper", "medium-replay"): "102.1 ± 1.8",
    ("hopper", "medium"): "92.3 ± 4.2",
    ("hopper", "random"): "31.6 ± 0.8",
    ("walker2d", "medium-expert"): "118.7 ± 0.2",
    ("walker2d", "medium-replay"): "89.2 ± 1.3",
    ("walker2d", "medium"): "104.3 ± 0.6",
    ("walker2d", "random"): "21.6 ± 1.4",
}


def paper_task(dataset_id: str) -> tuple[str, str] | None:
    """The paper's (env, quality) of a dataset id: ``halfcheetah/medium-v0`` -> ``("halfcheetah", "medium")``.

    :param dataset_id: Minari id (``halfcheetah/medium-v0``, ``mujoco/hopper/medium-v0``) or D4RL name
    :return: the task key of :data:`PAPER_TABLE_I`, or ``None``
    """
    name = dataset_id.lower()
    env = next((e for e in ("halfcheetah", "hopper", "walker2d") if e in name), None)
    if env is None:
        return None
    rest = name.split(env, 1)[1]
    for quality in ("medium-expert", "medium-replay", "medium", "random"):  # longest names first
        if re.search(rf"(^|[/_-]){quality}($|[/_-])", rest):
            return env, quality
    return None


# ----------------------------------------------------------------------------------------- presets


@dataclass
class Config:
    """Everything that decides a cell's result (a change of any field is another experiment).

    :param preset: name of the preset this came from
    :param steps: gradient steps per cell
    :param eval_freq: gradient steps between evaluations
    :param eval_episodes: episodes per evaluation
    :param batch_size: minibatch size
    :param net_arch: hidden sizes of actor and critics
    :param n_critics: critic ensemble size ``N``
    :param top_k: ``K`` smallest Q-values averaged in the policy loss
    :param n_action_samples: candidate actions per state at evaluation (picked by the critic)
    :param eval_rule: how the evaluations during training pick actions (:func:`apply_eval_rule`): ``ema``
        (the default: ``n_action_samples`` noise-free chains of the variant's predict actor), ``stochastic``
        (one sample of the EMA actor's noisy chain), ...; a rule other than ``ema`` overrides ``n_action_samples``
    :param dynamics_kwargs: arguments of the dynamics ensemble
    :param dynamics_fit_kwargs: arguments of its fit
    :param share_dynamics: fit the dynamics model once per dataset (first seed) and share it across seeds
    :param extra: further POLA keyword arguments
    :param log_interval: gradient steps between rows of the training statistics (``train/<cell>/``)
    """

    preset: str
    steps: int
    eval_freq: int
    eval_episodes: int
    batch_size: int = 256
    net_arch: list[int] = field(default_factory=lambda: [256, 256, 256])
    n_critics: int = 10
    top_k: int = 2
    n_action_samples: int = 1
    dynamics_kwargs: dict[str, Any] = field(default_factory=dict)
    dynamics_fit_kwargs: dict[str, Any] = field(default_factory=dict)
    share_dynamics: bool = False
    extra: dict[str, Any] = field(default_factory=dict)
    log_interval: int = 500
    eval_rule: str = "ema"

    def signature(self) -> str:
        """Short hash of the fields that decide results (the preset's name and the logging period excluded)."""
        data = {k: v for k, v in asdict(self).items() if k not in ("preset", "log_interval")}
        if data["eval_rule"] == "ema":  # the rule before it was a field: folders made then keep their signature
            del data["eval_rule"]
        # POLA's defaults where they depart from the paper's form (since 2026-12-02): a folder made under the old
        # defaults (the paper's form) keeps its signature, and cannot be resumed with the new ones by mistake
        changed = {key: value for key, value in pola_defaults(PAPER_FORM).items() if value != PAPER_FORM[key]}
        if changed:
            data["pola_defaults"] = changed
        return hashlib.sha1(json.dumps(data, sort_keys=True).encode()).hexdigest()[:10]


def pola_defaults(keys: Any) -> dict[str, Any]:
    """The defaults of these ``POLA`` arguments."""
    import inspect

    from sb3_pola.pola import POLA

    parameters = inspect.signature(POLA.__init__).parameters
    return {key: parameters[key].default for key in keys}


PRESETS: dict[str, Config] = {
    # a CPU core per cell: light nets, small ensemble, the main job's dynamics model, a short budget, the
    # compiled update (faster per step for the look-ahead variants; the first step compiles for minutes)
    "cpu": Config(
        preset="cpu",
        steps=10_000,
        eval_freq=2000,
        eval_episodes=10,
        batch_size=128,
        net_arch=[128, 128],
        n_critics=5,
        top_k=2,
        n_action_samples=1,
        dynamics_kwargs={"n_members": 5, "n_elites": 3, "hidden_dim": 128, "n_layers": 3},
        dynamics_fit_kwargs={"max_steps": 2000},
        share_dynamics=True,
        extra={"compile_update": True},
    ),
    # the paper's configuration (N = 10, 3 x 256, batch 256, the paper's form of the Q term), Diffusion-QL's
    # 50 candidate actions
    "paper": Config(
        preset="paper",
        steps=1_000_000,
        eval_freq=10_000,
        eval_episodes=10,
        batch_size=256,
        net_arch=[256, 256, 256],
        n_critics=10,
        top_k=2,
        n_action_samples=50,
        extra=dict(PAPER_FORM),
    ),
}
DEFAULT_DATASETS = ["halfcheetah/medium-v0", "halfcheetah/medium-replay-v0"]
DEFAULT_VARIANTS = ["T0", "T1", "T3", "T5", "T3-noproducts", "T3-criticproducts", "BC"]
CSV_FIELDS = ["dataset", "variant", "seed", "step", "score", "score_std", "mean_return", "eval_episodes", "wall_s", "success"]
REEVAL_FIELDS = ["dataset", "variant", "seed", "rule", "step", "score", "score_std", "mean_return", "eval_episodes", "success"]


def resolve_device(device: str) -> str:
    """``auto`` -> ``cuda`` when available, else ``cpu``."""
    if device != "auto":
        return device
    import torch as th

    return "cuda" if th.cuda.is_available() else "cpu"


def build_config(args: argparse.Namespace, device: str) -> Config:
    """The preset (``auto``: ``paper`` on CUDA, else ``cpu``) with the command line's overrides."""
    preset = args.preset if args.preset != "auto" else ("paper" if device.startswith("cuda") else "cpu")
    config = replace(PRESETS[preset])
    overrides = {
        "steps": args.steps,
        "eval_freq": args.eval_freq,
        "eval_episodes": args.eval_episodes,
        "batch_size": args.batch_size,
        "net_arch": args.net_arch,
        "n_critics": args.n_critics,
        "top_k": args.top_k,
        "n_action_samples": args.n_action_samples,
        "log_interval": args.log_interval,
        "eval_rule": args.eval_rule,
    }
    config = replace(config, **{k: v for k, v in overrides.items() if v is not None})
    if args.dynamics_steps is not None:
        config.dynamics_fit_kwargs = {**config.dynamics_fit_kwargs, "max_steps": args.dynamics_steps}
    if args.dynamics_kwargs:
        config.dynamics_kwargs = {**config.dynamics_kwargs, **json.loads(args.dynamics_kwargs)}
    if args.share_dynamics is not None:
        config.share_dynamics = args.share_dynamics
    if args.extra:
        config.extra = {**config.extra, **json.loads(args.extra)}
    if args.compile is not None:
        config.extra = {**config.extra, "compile_update": args.compile}
    config.top_k = min(config.top_k, config.n_critics)
    parse_eval_rule(config.eval_rule)
    if config.steps < 1 or config.eval_freq < 1 or config.eval_episodes < 1:
        raise ValueError("steps, eval_freq and eval_episodes must be positive")
    return config


# ----------------------------------------------------------------------------------------- one cell


def slug(text: str) -> str:
    """File-name-safe version of a dataset id or variant."""
    return re.sub(r"[^A-Za-z0-9.-]+", "_", text).strip("_")


def cell_name(dataset: str, variant: str, seed: int) -> str:
    return f"{slug(dataset)}__{variant}__seed{seed}"


def evaluate(
    model: Any, env: Any, n_episodes: int, seed: int, deterministic: bool = True, successes: list[bool | None] | None = None
) -> np.ndarray:
    """Returns of ``n_episodes`` episodes of the model's policy (episode ``i`` reset with ``seed + i``).

    :param model: a POLA model
    :param env: a Gymnasium env (not vectorised)
    :param n_episodes: number of episodes
    :param seed: seed of the first episode's reset; with ``deterministic=False`` it also seeds torch, so the
        sampled actions repeat (the caller's torch RNG state is restored afterwards, so an evaluation during
        training leaves the training's random stream as it was)
    :param deterministic: ``model.predict``'s flag
    :param successes: if a list, it receives one entry per episode: whether a step's ``info["success"]`` (or
        ``info["is_success"]``) was true, as goal-reaching envs such as Gymnasium-Robotics' mazes report it, or
        ``None`` when the env reports no success
    :return: ``[n_episodes]`` undiscounted returns
    """
    import torch as th

    successes = [] if successes is None else successes
    if deterministic:
        return _episode_returns(model, env, n_episodes, seed, deterministic, successes)
    devices = list(range(th.cuda.device_count())) if th.cuda.is_initialized() else []
    with th.random.fork_rng(devices=devices):
        th.manual_seed(seed)
        return _episode_returns(model, env, n_episodes, seed, deterministic, successes)


def _episode_returns(
    model: Any, env: Any, n_episodes: int, seed: int, deterministic: bool, successes: list[bool | None]
) -> np.ndarray:
    returns = np.zeros(n_episodes)
    for i in range(n_episodes):
        obs, _ = env.reset(seed=seed + i)
        done, success = False, None
        while not done:
            action, _ = model.predict(obs, deterministic=deterministic)
            obs, reward, terminated, truncated, info = env.step(action)
            returns[i] += float(reward)
            done = terminated or truncated
            success = update_success(success, info)
        successes.append(success)
    return returns


def evaluation_scores(model: Any, env: Any, n_episodes: int, seed: int, deterministic: bool = True) -> dict[str, Any]:
    """The CSV columns of one evaluation of a cell's model (the resets of seed ``seed``'s protocol)."""
    successes: list[bool | None] = []
    returns = evaluate(model, env, n_episodes, seed=10_000 * (seed + 1), deterministic=deterministic, successes=successes)
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


def read_rows(csv_path: pathlib.Path) -> list[dict[str, Any]]:
    """Rows of ``scores.csv`` with numbers parsed (empty list if there is no file)."""
    if not csv_path.exists():
        return []
    rows = []
    with csv_path.open(newline="") as f:
        for row in csv.DictReader(f):
            parsed: dict[str, Any] = dict(row)
            parsed["seed"], parsed["step"], parsed["eval_episodes"] = (
                int(row["seed"]),
                int(row["step"]),
                int(row["eval_episodes"]),
            )
            for key in ("score", "score_std", "mean_return", "wall_s", "success"):
                value = row.get(key)  # success: absent in files written before it was a column
                parsed[key] = float(value) if value not in (None, "", "None") else math.nan
            rows.append(parsed)
    return rows


def write_rows(csv_path: pathlib.Path, rows: list[dict[str, Any]]) -> None:
    """Rewrite ``scores.csv`` atomically."""
    tmp = csv_path.with_suffix(".tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_FIELDS)
        writer.writeheader()
        writer.writerows({k: row.get(k, math.nan) for k in CSV_FIELDS} for row in rows)
    tmp.replace(csv_path)


def _csv_header(csv_path: pathlib.Path) -> list[str]:
    with csv_path.open(newline="") as f:
        return next(csv.reader(f), [])


def append_row(csv_path: pathlib.Path, row: dict[str, Any]) -> None:
    """Append one row to ``scores.csv`` (first rewriting a file from before the ``success`` column with it)."""
    if csv_path.exists() and _csv_header(csv_path) != CSV_FIELDS:
        write_rows(csv_path, read_rows(csv_path))
    new = not csv_path.exists()
    with csv_path.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_FIELDS)
        if new:
            writer.writeheader()
        writer.writerow({k: row.get(k, math.nan) for k in CSV_FIELDS})
        f.flush()


def pola_kwargs(extra: dict[str, Any]) -> dict[str, Any]:
    """POLA keyword arguments from JSON-able ones: ``"eta_warmup": [warmup, ramp]`` becomes a
    :class:`~sb3_pola.common.schedules.WarmupSchedule` of ``eta`` (behaviour cloning, then a linear ramp)."""
    kwargs = dict(extra)
    if "eta_warmup" in kwargs:
        from sb3_pola.common.schedules import WarmupSchedule

        warmup, ramp = kwargs.pop("eta_warmup")
        if kwargs.get("eta", 1.0) != 0:  # behaviour cloning stays behaviour cloning
            kwargs["eta"] = WarmupSchedule(float(kwargs.get("eta", 1.0)), warmup, ramp)
    return kwargs


def _train_logger(folder: pathlib.Path, done_steps: int) -> Any:
    """An SB3 logger writing ``train/*`` statistics to ``folder/progress_from<step>.csv`` (a file per resumed segment)."""
    from stable_baselines3.common.logger import CSVOutputFormat, Logger

    folder.mkdir(parents=True, exist_ok=True)
    return Logger(folder=str(folder), output_formats=[CSVOutputFormat(str(folder / f"progress_from{done_steps}.csv"))])


def dynamics_path(out: pathlib.Path, dataset: str, seed: int, config: Config) -> pathlib.Path:
    """Where a cell's fitted dynamics model is kept: one per dataset with ``share_dynamics``, else one per (dataset, seed)."""
    dyn_seed = "shared" if config.share_dynamics else f"seed{seed}"
    return out / "dynamics" / f"{slug(dataset)}__{dyn_seed}.pt"


def needs_dynamics(variant: str, config: Config) -> bool:
    """Whether a variant's model has a dynamics model to fit (a look-ahead, ``rollout_length > 0``)."""
    default = pola_defaults(["rollout_length"])["rollout_length"]
    return int(pola_kwargs({**config.extra, **VARIANTS[variant][1]}).get("rollout_length", default)) > 0


def new_cell_model(variant: str, seed: int, config: Config, dataset: str, device: str) -> Any:
    """A fresh POLA model of a cell: the variant's arguments over the config's.

    :param variant: a key of :data:`VARIANTS`
    :param seed: random seed
    :param config: budget and hyperparameters
    :param dataset: Minari dataset id
    :param device: torch device
    :return: the model
    """
    from sb3_pola.pola import POLA

    _, kwargs, policy_kwargs = VARIANTS[variant]
    return POLA(
        "MlpPolicy",
        dataset=dataset,
        batch_size=config.batch_size,
        n_critics=config.n_critics,
        top_k=config.top_k,
        dynamics_kwargs=config.dynamics_kwargs,
        dynamics_fit_kwargs=config.dynamics_fit_kwargs,
        policy_kwargs={"net_arch": config.net_arch, "n_action_samples": config.n_action_samples, **policy_kwargs},
        seed=seed,
        device=device,
        **pola_kwargs({**config.extra, **kwargs}),
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
    from stable_baselines3.common.callbacks import BaseCallback

    from sb3_pola.common.checkpoint import load_module_state, load_or_make, save_checkpoint, save_module_state
    from sb3_pola.common.datasets import make_env
    from sb3_pola.pola import POLA

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


def rows_rel(dataset: str, variant: str, seed: int) -> str:
    """A cell's own rows file (``rows/<cell>.csv``, relative to the output), merged into ``scores.csv`` by the driver."""
    return f"rows/{cell_name(dataset, variant, seed)}.csv"


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

    :param view: the workspace of the output (:func:`~sb3_pola.experiments.storage.open_workspace`)
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


# ----------------------------------------------------------------------------------------- re-evaluation


def apply_eval_rule(model: Any, rule: str) -> bool:
    """Set how ``model.predict`` picks actions; return the ``deterministic`` flag to call it with.

    :param model: a POLA model
    :param rule: ``ema`` (the noise-free chain of the EMA actor, the default), ``online`` (the same chain of
        the trained actor), ``stochastic`` / ``online-stochastic`` (one sample of the noisy reverse chain, the
        policy Diffusion-QL trains) or ``candidates<N>`` / ``online-candidates<N>`` (N noisy candidates of the
        EMA / online actor, the one with the highest pessimistic Q kept, as Diffusion-QL evaluates)
    """
    model.policy.predict_actor, model.policy.n_action_samples, deterministic = parse_eval_rule(rule)
    return deterministic


def parse_eval_rule(rule: str) -> tuple[str, int, bool]:
    """``(predict_actor, n_action_samples, deterministic)`` of an evaluation rule (see :func:`apply_eval_rule`)."""
    match = re.fullmatch(r"(online-)?(stochastic|candidates(\d+))", rule)
    if rule in ("ema", "online"):
        return rule, 1, True
    if match is None or (match.group(3) is not None and int(match.group(3)) < 1):
        raise ValueError(f"unknown evaluation rule {rule!r}: ema, online, [online-]stochastic or [online-]candidates<N>")
    actor = "online" if match.group(1) else "ema"
    if match.group(2) == "stochastic":
        return actor, 1, False
    return actor, int(match.group(3)), True


def reevaluate(out: pathlib.Path, rules: list[str], episodes: int, device: str, verbose: int = 1) -> list[dict[str, Any]]:
    """Evaluate every saved final model of ``out/models`` under each rule; rows go to ``reeval.csv``, a table to ``reeval.md``.

    Episodes use the same reset seeds as the score run, so ``ema`` reproduces the run's final evaluation.
    Finished (model, rule) pairs in ``reeval.csv`` are skipped.
    """
    from sb3_pola.common.datasets import make_env
    from sb3_pola.pola import POLA

    for rule in rules:  # unknown rules fail before any model is loaded
        parse_eval_rule(rule)
    csv_path = out / "reeval.csv"
    done: set[tuple[str, str]] = set()
    if csv_path.exists():
        with csv_path.open(newline="") as f:
            done = {(r["dataset"] + r["variant"] + r["seed"], r["rule"]) for r in csv.DictReader(f)}
    for path in sorted((out / "models").glob("*.zip")):
        marker_path = out / "cells" / f"{path.stem}.json"
        if not marker_path.exists():  # a cell finishing right now: its marker follows its model
            continue
        marker = json.loads(marker_path.read_text())
        dataset, variant, seed = marker["dataset"], marker["variant"], int(marker["seed"])
        model = POLA.load(path, device=device)
        env = make_env(dataset)
        for rule in rules:
            if (dataset + variant + str(seed), rule) in done:
                continue
            deterministic = apply_eval_rule(model, rule)
            row = {
                "dataset": dataset,
                "variant": variant,
                "seed": seed,
                "rule": rule,
                "step": model.num_timesteps,
                **evaluation_scores(model, env, episodes, seed, deterministic=deterministic),
            }
            if csv_path.exists() and _csv_header(csv_path) != REEVAL_FIELDS:  # a file from before the success column
                with csv_path.open(newline="") as f:
                    old_rows = list(csv.DictReader(f))
                with csv_path.open("w", newline="") as f:
                    writer = csv.DictWriter(f, fieldnames=REEVAL_FIELDS, restval="nan")
                    writer.writeheader()
                    writer.writerows(old_rows)
            new = not csv_path.exists()
            with csv_path.open("a", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=REEVAL_FIELDS)
                if new:
                    writer.writeheader()
                writer.writerow(row)
            if verbose:
                print(f"[score] re-evaluated {path.stem} under {rule}: {row['score']:.1f}")
        env.close()
    with csv_path.open(newline="") as f:
        rows: list[dict[str, Any]] = [dict(r) for r in csv.DictReader(f)]
    by_key: dict[tuple[str, str, str], list[float]] = defaultdict(list)
    success_by_key: dict[tuple[str, str, str], list[float]] = defaultdict(list)
    for r in rows:
        by_key[(r["dataset"], r["variant"], r["rule"])].append(float(r["score"]))
        success_by_key[(r["dataset"], r["variant"], r["rule"])].append(float(r.get("success") or "nan"))
    with_success = any(not math.isnan(v) for values in success_by_key.values() for v in values)
    head = "| dataset | variant | rule | score | seeds |" + (" success rate | seeds |" if with_success else "")
    lines = [head, "|---|---|---|---|---|" + ("---|---|" if with_success else "")]
    for (dataset, variant, rule), values in sorted(by_key.items()):
        per_seed = ", ".join(f"{v:.1f}" for v in values)
        line = f"| {dataset} | {variant} | {rule} | {_fmt(values)} | {per_seed} |"
        if with_success:
            rates = success_by_key[(dataset, variant, rule)]
            line += f" {_fmt_rate(rates)} | {', '.join(f'{v:.2f}' for v in rates)} |"
        lines.append(line)
    (out / "reeval.md").write_text("\n".join(lines) + "\n")
    return rows


# ----------------------------------------------------------------------------------------- reports

# d3rlpy baselines of ``sb3-pola peers`` (``peers.csv`` next to ``scores.csv``): table rows after POLA's, curves
PEER_VARIANTS = ["d3rlpy-TD3+BC", "d3rlpy-IQL", "d3rlpy-BC"]
PEER_STYLES: dict[str, tuple[str, str]] = {
    "d3rlpy-TD3+BC": ("tab:brown", "--"),
    "d3rlpy-IQL": ("tab:pink", "-."),
    "d3rlpy-BC": ("goldenrod", ":"),
}


def is_peer(variant: str) -> bool:
    """Whether a variant is a d3rlpy baseline (``d3rlpy-*``, from ``peers.csv``)."""
    return variant.startswith("d3rlpy-")


def _fmt_rate(values: list[float]) -> str:
    values = [v for v in values if not math.isnan(v)]
    if not values:
        return "-"
    if len(values) == 1:
        return f"{values[0]:.2f}"
    return f"{np.mean(values):.2f} ± {np.std(values, ddof=1):.2f}"


def _fmt(values: list[float]) -> str:
    values = [v for v in values if not math.isnan(v)]
    if not values:
        return "-"
    if len(values) == 1:
        return f"{values[0]:.1f}"  # one seed: no spread to show
    return f"{np.mean(values):.1f} ± {np.std(values, ddof=1):.1f}"


def summarize(rows: list[dict[str, Any]]) -> dict[tuple[str, str], dict[str, Any]]:
    """Per (dataset, variant): final and best score per seed, the last step reached and the seeds.

    ``final`` is the score of each seed's last evaluation, ``best`` the maximum over its evaluations.
    """
    by_cell: dict[tuple[str, str, int], list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        by_cell[(row["dataset"], row["variant"], row["seed"])].append(row)
    out: dict[tuple[str, str], dict[str, Any]] = {}
    for (dataset, variant, seed), cell in sorted(by_cell.items()):
        cell.sort(key=lambda r: r["step"])
        entry = out.setdefault(
            (dataset, variant), {"final": [], "best": [], "steps": [], "seeds": [], "wall_s": [], "success": []}
        )
        entry["final"].append(cell[-1]["score"])
        entry["success"].append(cell[-1].get("success", math.nan))
        entry["best"].append(max(r["score"] for r in cell))
        entry["steps"].append(cell[-1]["step"])
        entry["seeds"].append(seed)
        entry["wall_s"].append(cell[-1]["wall_s"])
    return out


def dataset_score(dataset: str) -> float | None:
    """Mean normalised return of the dataset's own episodes (what pure imitation would reach)."""
    try:
        from sb3_pola.common.datasets import load_offline_dataset

        data = load_offline_dataset(dataset)
        if len(data.episode_returns) == 0:
            return None
        return data.normalized_score(data.episode_returns)
    except Exception:  # a report must not fail on a dataset that moved
        return None


def markdown_table(
    rows: list[dict[str, Any]],
    variants: list[str],
    config: dict[str, Any] | None = None,
    peers_config: dict[str, Any] | None = None,
) -> str:
    """Table-I-style markdown: one line per (dataset, variant), final and best score mean ± std over seeds.

    Rows of d3rlpy baselines (variants ``d3rlpy-*``, from ``peers.csv``) come after each dataset's POLA rows;
    ``peers_config`` (``peers_config.json``) describes their budget and d3rlpy version.
    """
    summary = summarize(rows)
    lines = []
    if config:
        lines.append(
            f"Budget: {config.get('steps')} gradient steps per run, evaluation every {config.get('eval_freq')} steps "
            f"on {config.get('eval_episodes')} episodes (preset `{config.get('preset')}`, device {config.get('device')}), "
            f"evaluation rule `{config.get('eval_rule', 'ema')}`."
        )
        lines.append("")
    if any(is_peer(v) for (_, v) in summary):
        text = "Rows `d3rlpy-*`: d3rlpy baselines (`sb3-pola peers`, `peers.csv`) trained on the same arrays"
        if peers_config:
            version = peers_config.get("versions", {}).get("d3rlpy", "?")
            text += (
                f", d3rlpy {version}, {peers_config.get('steps')} gradient steps per run, evaluation every "
                f"{peers_config.get('eval_freq')} steps on {peers_config.get('eval_episodes')} episodes"
            )
        text += (
            " with the same evaluation protocol (deterministic actions, the same reset seeds, D4RL-normalised); "
            "d3rlpy's hyperparameters: TD3+BC alpha 2.5 on standardised states, IQL with return-based reward "
            "scaling (x1000) and a cosine actor learning rate, BC (deterministic, MSE)."
        )
        lines.append(text)
        lines.append("")
    # goal-reaching envs (mazes) report success: a column of the final evaluations' success rates
    with_success = any(not math.isnan(v) for entry in summary.values() for v in entry["success"])
    success_head, success_rule = (" final success rate |", "---|") if with_success else ("", "")
    lines.append(
        "| dataset | variant | final | best | seeds | steps | wall s / run | dataset mean | paper POLA (D4RL v2) |"
        + success_head
    )
    lines.append("|---|---|---|---|---|---|---|---|---|" + success_rule)
    datasets = list(dict.fromkeys(r["dataset"] for r in rows))
    for dataset in datasets:
        task = paper_task(dataset)
        paper = PAPER_TABLE_I.get(task, "-") if task else "-"
        data_score = dataset_score(dataset)
        data_text = "-" if data_score is None else f"{data_score:.1f}"
        ordered = [v for v in variants if (dataset, v) in summary] + sorted(
            v for (d, v) in summary if d == dataset and v not in variants and not is_peer(v)
        )
        peers = [v for (d, v) in summary if d == dataset and is_peer(v)]
        ordered += [v for v in PEER_VARIANTS if v in peers] + sorted(v for v in peers if v not in PEER_VARIANTS)
        for variant in ordered:
            entry = summary[(dataset, variant)]
            steps = "/".join(str(s) for s in sorted(set(entry["steps"])))
            seeds = ",".join(str(s) for s in entry["seeds"])
            wall = f"{np.mean(entry['wall_s']):.0f}"
            lines.append(
                f"| {dataset} | {variant} | {_fmt(entry['final'])} | {_fmt(entry['best'])} | {seeds} | {steps} | {wall} "
                f"| {data_text} | {paper} |" + (f" {_fmt_rate(entry['success'])} |" if with_success else "")
            )
    lines.append("")
    lines.append(
        "final: score of the last evaluation; best: best evaluation of each run; mean ± sample std over seeds "
        "(a single number: one seed). Scores are D4RL-normalised (100 = the dataset's reference expert)."
        + (" Success rate: the fraction of the final evaluation's episodes that reached the goal." if with_success else "")
    )
    return "\n".join(lines) + "\n"


def plot_curves(rows: list[dict[str, Any]], out: pathlib.Path) -> list[pathlib.Path]:
    """Learning curves like the paper's Fig. 3 (rollout length) and Fig. 4 (products), a PNG per dataset and figure.

    d3rlpy baselines (``d3rlpy-*`` rows): TD3+BC is drawn dashed in both figures, and ``fig_peers_<dataset>.png``
    shows every baseline next to POLA's T0, T3 and BC (those present).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves: dict[tuple[str, str], dict[int, dict[int, float]]] = defaultdict(lambda: defaultdict(dict))
    for row in rows:
        curves[(row["dataset"], row["variant"])][row["step"]][row["seed"]] = row["score"]
    written = []
    colors = {
        "T0": "tab:blue",
        "T1": "tab:orange",
        "T3": "tab:red",
        "T5": "tab:green",
        "T3-noproducts": "tab:cyan",
        "T0-noproducts": "tab:olive",
        "T3-criticproducts": "tab:purple",
        "T3-floor": "tab:brown",
        "T0-floor": "tab:pink",
        "BC": "tab:gray",
    }
    for dataset in dict.fromkeys(r["dataset"] for r in rows):
        data_score = dataset_score(dataset)
        figures = {**FIGURES, "peers": ["T0", "T3", "BC", *PEER_VARIANTS]}
        for figure, members in figures.items():
            present = [v for v in members if (dataset, v) in curves]
            if figure == "peers":
                if not any(is_peer(v) for v in present):
                    continue
                present += sorted(v for (d, v) in curves if d == dataset and is_peer(v) and v not in present)
            elif len([v for v in present if v != "BC"]) < 2:
                continue  # a comparison needs two variants
            else:
                present += [v for v in PEER_VARIANTS[:1] if (dataset, v) in curves]  # TD3+BC, dashed
            fig, ax = plt.subplots(figsize=(5.5, 3.6), dpi=90)
            for variant in present:
                by_step = curves[(dataset, variant)]
                steps = sorted(by_step)
                mean = np.array([np.mean(list(by_step[s].values())) for s in steps])
                std = np.array([np.std(list(by_step[s].values())) for s in steps])
                n_seeds = max(len(by_step[s]) for s in steps)
                style = "--" if variant == "BC" else "-"
                color = colors.get(variant)
                if is_peer(variant):
                    color, style = PEER_STYLES.get(variant, ("black", "--"))
                label = VARIANTS[variant][0] if variant in VARIANTS else variant
                ax.plot(steps, mean, style, marker="o", ms=3, color=color, label=f"{label} (n={n_seeds})")
                if n_seeds > 1:
                    ax.fill_between(steps, mean - std, mean + std, color=color, alpha=0.15)
            if data_score is not None:
                ax.axhline(data_score, color="black", ls=":", lw=1, label="dataset mean")
            title = {"rollout": "rollout length T", "products": "state products"}.get(figure, "d3rlpy baselines")
            ax.set_title(f"{dataset}: {title}", fontsize=10)
            ax.set_xlabel("gradient steps")
            ax.set_ylabel("normalised score")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
            fig.tight_layout()
            path = out / f"fig_{figure}_{slug(dataset)}.png"
            fig.savefig(path)
            plt.close(fig)
            written.append(path)
    return written


def write_reports(out: pathlib.Path, variants: list[str], config: dict[str, Any] | None = None, shown: str = "") -> None:
    """``table.md`` and the figures from ``scores.csv``, with the d3rlpy baselines of ``peers.csv`` when it exists.

    :param out: output folder
    :param variants: the variants of the table, in order
    :param config: the content of ``config.json``
    :param shown: how the output is named in messages (default: the folder)
    """
    shown = (shown or str(out)).rstrip("/")
    rows = read_rows(out / "scores.csv")
    peer_rows = [r for r in read_rows(out / "peers.csv") if is_peer(r["variant"])]
    if not rows and not peer_rows:
        print(f"[score] no evaluations in {shown}/scores.csv yet")
        return
    peers_path = out / "peers_config.json"
    peers_config = json.loads(peers_path.read_text()) if peer_rows and peers_path.exists() else None
    rows = rows + peer_rows
    (out / "table.md").write_text(markdown_table(rows, variants, config, peers_config))
    paths = plot_curves(rows, out)
    print(f"[score] wrote {shown}/table.md" + "".join(f", {p.name}" for p in paths))


def publish_reports(view: Workspace, variants: list[str], config: dict[str, Any] | None = None) -> None:
    """:func:`write_reports` and ``diagnostics.md`` in a workspace: their inputs pulled, the outputs pushed.

    :param view: the workspace of the output
    :param variants: the variants of the table, in order
    :param config: the content of ``config.json``
    """
    view.pull("scores.csv", "peers.csv", "peers_config.json")
    view.pull_tree("train")
    write_reports(view.folder, variants, config, shown=view.shown())
    write_diagnostics(view.folder)
    view.push("table.md", "diagnostics.md", *sorted(view.folder.glob("fig_*.png")))


# ----------------------------------------------------------------------------------------- command line


def machine_info(device: str) -> str:
    cpu = platform.processor() or platform.machine()
    try:  # Linux: the CPU's model name
        cpu = next(line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    text = f"{cpu}, {os.cpu_count()} CPU cores"
    if device.startswith("cuda"):
        import torch as th

        text += f", {th.cuda.get_device_name(0)}"
    return text


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="sb3-pola score",
        description="Train POLA and its ablations over datasets and seeds; write scores.csv, table.md and learning curves.",
    )
    parser.add_argument("--preset", choices=["auto", *PRESETS], default="auto", help="auto: paper on CUDA, cpu otherwise")
    parser.add_argument("--datasets", nargs="+", default=DEFAULT_DATASETS, help="Minari dataset ids")
    parser.add_argument("--variants", nargs="+", default=DEFAULT_VARIANTS, choices=ALL_VARIANTS, metavar="VARIANT")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--steps", type=int, help="gradient steps per run")
    parser.add_argument("--eval-freq", type=int, help="gradient steps between evaluations")
    parser.add_argument("--eval-episodes", type=int, help="episodes per evaluation")
    parser.add_argument("--batch-size", type=int)
    parser.add_argument("--net-arch", type=int, nargs="+", help="hidden sizes of actor and critics")
    parser.add_argument("--n-critics", type=int)
    parser.add_argument("--top-k", type=int)
    parser.add_argument("--n-action-samples", type=int, help="candidate actions per state at evaluation")
    parser.add_argument("--dynamics-steps", type=int, help="cap on the dynamics model's fit (gradient steps)")
    parser.add_argument("--dynamics-kwargs", help="JSON of EnsembleDynamics arguments, e.g. '{\"hidden_dim\": 128}'")
    parser.add_argument(
        "--share-dynamics", action=argparse.BooleanOptionalAction, default=None, help="one dynamics fit per dataset"
    )
    parser.add_argument("--extra", help="JSON of further POLA arguments, e.g. '{\"eta\": 0.5}'")
    parser.add_argument(
        "--compile", action=argparse.BooleanOptionalAction, default=None, help="compile_update (the cpu preset: on)"
    )
    parser.add_argument("--device", default="auto", help="cpu, cuda, cuda:1 or auto")
    parser.add_argument("--data-dir", help="folder of the Minari datasets (sets MINARI_DATASETS_PATH)")
    parser.add_argument(
        "--out", default="outputs/score", help="output folder, or an fsspec URL (s3://bucket/run with s3fs installed, ...)"
    )
    parser.add_argument("--threads", type=int, help="torch CPU threads")
    parser.add_argument("--log-interval", type=int, help="gradient steps between rows of the training statistics")
    parser.add_argument(
        "--eval-rule",
        metavar="RULE",
        help="how the evaluations during training act: ema (default: the EMA actor's noise-free chain), online, "
        "[online-]stochastic (one sample of the noisy chain), [online-]candidates<N>",
    )
    parser.add_argument(
        "--reevaluate",
        nargs="+",
        metavar="RULE",
        help="re-evaluate the saved final models under these rules: ema, online, [online-]stochastic, [online-]candidates<N>",
    )
    parser.add_argument(
        "--ray",
        nargs="?",
        const="local",
        metavar="ADDRESS",
        help="run the cells as Ray tasks: no ADDRESS starts Ray on this machine, 'auto' or host:port joins a cluster",
    )
    parser.add_argument("--cpus-per-cell", type=float, default=1.0, help="with --ray: CPUs reserved per cell")
    parser.add_argument("--gpus-per-cell", type=float, default=0.0, help="with --ray: GPUs per cell (0.25: four per GPU)")
    parser.add_argument("--max-retries", type=int, default=3, help="with --ray: reruns of a cell whose worker died")
    parser.add_argument("--report-only", action="store_true", help="only rewrite table.md and the figures from scores.csv")
    parser.add_argument("--dry-run", action="store_true", help="print the resolved configuration and the cells, run nothing")
    parser.add_argument("-v", "--verbose", type=int, default=1)
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """``sb3-pola score``; returns the exit code."""
    from sb3_pola.experiments.storage import Storage, is_url, open_workspace

    args = parse_args(argv)
    if is_url(args.out):
        try:
            Storage(args.out)
        except (ImportError, ValueError) as error:  # the URL's fsspec backend is missing, or an unknown protocol
            print(f"[score] --out {args.out}: {error}", file=sys.stderr)
            return 2
    with open_workspace(args.out) as view:
        if args.data_dir:
            os.environ["MINARI_DATASETS_PATH"] = str(pathlib.Path(args.data_dir).resolve())
        return _main(args, argv, view)


def _main(args: argparse.Namespace, argv: list[str] | None, view: Workspace) -> int:
    """``sb3-pola score`` with its output's workspace opened (:func:`main`)."""
    out = view.folder
    config_path = out / "config.json"
    view.pull("config.json")
    if args.report_only:
        saved = json.loads(config_path.read_text()) if config_path.exists() else None
        publish_reports(view, args.variants, saved)
        return 0
    if args.threads:
        import torch as th

        th.set_num_threads(args.threads)
    # the cells run on the cluster's GPUs, not on the driver's
    device = "cuda" if args.ray and args.gpus_per_cell > 0 and args.device == "auto" else resolve_device(args.device)
    if args.reevaluate:
        return _reevaluate_in(view, args, device)
    config = build_config(args, device)
    cells = [(d, v, s) for s in args.seeds for d in args.datasets for v in args.variants]
    info = {
        **asdict(config),
        "signature": config.signature(),
        "device": device,
        "machine": machine_info(device),
        "date": datetime.date.today().isoformat(),
        "command": "sb3-pola score " + " ".join(sys.argv[1:] if argv is None else argv),
    }
    if config_path.exists():
        saved = json.loads(config_path.read_text())
        if saved.get("signature") != config.signature():
            print(
                f"[score] {args.out} holds runs of another configuration (signature {saved.get('signature')}, this one "
                f"{config.signature()}): use another --out, or the same options",
                file=sys.stderr,
            )
            return 2
        info["started"] = saved.get("started", info["date"])
    else:
        info["started"] = info["date"]
    print(f"[score] preset {config.preset} on {device}: {len(cells)} runs of {config.steps} steps -> {args.out}")
    if args.dry_run:
        print(json.dumps(info, indent=1))
        return 0
    config_path.write_text(json.dumps(info, indent=1))
    view.push("config.json")
    if args.ray:
        from sb3_pola.experiments.ray_grid import run_grid

        return run_grid(args, cells, config, info, view, device)
    if view.storage is not None:
        return _run_stored_sequential(args, cells, config, info, view, device)
    for dataset, variant, seed in cells:
        marker = out / "cells" / f"{cell_name(dataset, variant, seed)}.json"
        if marker.exists():
            if args.verbose:
                print(f"[score] {marker.stem}: done, skipped")
            continue
        run_cell(dataset, variant, seed, config, out, device, verbose=args.verbose)
        publish_reports(view, args.variants, info)
    publish_reports(view, args.variants, info)
    return 0


def _reevaluate_in(view: Workspace, args: argparse.Namespace, device: str) -> int:
    """``--reevaluate``: the saved models and markers pulled, ``reeval.csv`` and ``reeval.md`` pushed."""
    for rule in args.reevaluate:  # unknown rules fail before any model is downloaded
        parse_eval_rule(rule)
    config_path = view.folder / "config.json"
    saved = json.loads(config_path.read_text()) if config_path.exists() else {}
    episodes = args.eval_episodes or int(saved.get("eval_episodes", 10))
    view.pull("reeval.csv")
    view.pull_tree("cells")
    view.pull_tree("models")
    reevaluate(view.folder, args.reevaluate, episodes, device, verbose=args.verbose)
    view.push("reeval.csv", "reeval.md")
    print(f"[score] wrote {view.shown('reeval.md')}")
    return 0


def _run_stored_sequential(
    args: argparse.Namespace,
    cells: list[tuple[str, str, int]],
    config: Config,
    info: dict[str, Any],
    view: Workspace,
    device: str,
) -> int:
    """The cells one after another into an fsspec URL, as the Ray workers run them (:func:`run_stored_cell`).

    Each cell works in a scratch folder of its own (deleted after it) and writes ``rows/<cell>.csv``; after every
    cell the rows are merged into ``scores.csv`` and the reports rewritten.

    :param args: the ``sb3-pola score`` arguments
    :param cells: the grid, in order
    :param config: its configuration
    :param info: the content of ``config.json``
    :param view: the driver's workspace of the output
    :param device: torch device
    :return: the exit code
    """
    from sb3_pola.experiments.ray_grid import merge_rows
    from sb3_pola.experiments.storage import open_workspace

    for cell in cells:
        if view.exists(f"cells/{cell_name(*cell)}.json"):
            if args.verbose:
                print(f"[score] {cell_name(*cell)}: done, skipped")
            continue
        with open_workspace(view.location) as cell_view:
            run_stored_cell(cell_view, *cell, config, device, verbose=args.verbose)
        merge_rows(view, cells)
        publish_reports(view, args.variants, info)
    merge_rows(view, cells)
    publish_reports(view, args.variants, info)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
