"""One d3rlpy baseline cell of ``sb3-pola peers``, run by the peers venv's Python (d3rlpy 2.8.1, gymnasium 1.0).

This file is a script, not part of the package's import graph: it imports only the standard
library, numpy, gymnasium, torch and d3rlpy (never ``sb3_pola``; the normalised score comes from
``sb3_pola/common/metrics.py``, loaded by its path), so the separate virtual environment that holds d3rlpy
can run it directly::

    .venv-peers/bin/python peers_worker.py --npz data.npz --algo td3bc --seed 0 --steps 10000 \\
        --eval-freq 2000 --eval-episodes 10 --csv out/peers.csv --dataset halfcheetah/medium-v0

Data. ``--npz`` is written by ``sb3_pola.grid.peers.export_dataset`` from our
``OfflineDataset``: flat transitions (``observations``, ``actions`` in [-1, 1], ``rewards``,
``next_observations``, ``terminals``, ``timeouts``) where every episode ends with exactly one of
``terminals`` (the env terminated) or ``timeouts`` (truncated, or cut by the end of the data).

d3rlpy 2.x has no next-observation input: ``MDPDataset`` cuts episodes after each terminal or
timeout flag and its ``BasicTransitionPicker`` pairs step ``i`` with observation ``i + 1`` of the
same episode; the last step of a terminated episode gets a zero next observation (masked by its
terminal flag), and the last step of a timed-out episode is *not a transition* (it has no next
observation). Fed our flat arrays as they are, that would drop the last transition of every
truncated episode. :func:`prepare_episode_arrays` therefore appends to each timed-out episode one
extra row holding its final next observation (zero action and reward, the timeout flag moved onto
it): d3rlpy then sees exactly our transitions, each paired with the dataset's own next observation,
and never with the first observation of the next episode. :func:`check_alignment` verifies this on
the built dataset through d3rlpy's own transition picker before every training run.

Resume: with ``--ckpt``, the model, its optimisers, the gradient step and the random states are
saved at every evaluation; a run started again with the same arguments continues from there (the
cell's rows after that step are dropped from ``--csv``), otherwise its rows are dropped and it starts
from scratch.

Evaluation is ``sb3-pola score``'s protocol: deterministic actions (d3rlpy's ``predict``), episode
``i`` reset with seed ``10_000 * (seed + 1) + i``, actions mapped from [-1, 1] to the env's bounds,
score ``100 (R - ref_min) / (ref_max - ref_min)`` per episode, mean and std over the episodes.
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import io
import json
import os
import pathlib
import pickle
import random
import sys
import time
from typing import Any

import numpy as np

VARIANT_NAMES = {"td3bc": "d3rlpy-TD3+BC", "iql": "d3rlpy-IQL", "bc": "d3rlpy-BC"}
# the npz arrays of one transition each
TRANSITION_FIELDS = ("observations", "actions", "rewards", "next_observations", "terminals", "timeouts")


# ----------------------------------------------------------------------------------------- data (numpy only)


def load_npz(path: str | os.PathLike) -> dict[str, Any]:
    """The arrays and metadata of an exported dataset (strings and scalars unwrapped)."""
    with np.load(path, allow_pickle=False) as data:
        out: dict[str, Any] = {name: data[name] for name in data.files}
    for key in ("dataset_id", "env_id", "env_kwargs", "dict_keys"):
        if key in out:
            out[key] = str(out[key])
    for key in ("ref_min_score", "ref_max_score"):
        if key in out:
            value = float(out[key])
            out[key] = None if np.isnan(value) else value
    if "max_episode_steps" in out:
        steps = int(out["max_episode_steps"])
        out["max_episode_steps"] = None if steps <= 0 else steps
    return out


def episode_ends(terminals: np.ndarray, timeouts: np.ndarray) -> np.ndarray:
    """Indices of the last step of each episode (a terminal or a timeout flag; never both)."""
    terminals, timeouts = np.asarray(terminals) > 0, np.asarray(timeouts) > 0
    if np.any(terminals & timeouts):
        raise ValueError("a step is flagged both terminal and timeout")
    if len(terminals) and not (terminals[-1] or timeouts[-1]):
        raise ValueError("the last step ends no episode (neither terminal nor timeout)")
    return np.flatnonzero(terminals | timeouts)


def prepare_episode_arrays(
    observations: np.ndarray,
    actions: np.ndarray,
    rewards: np.ndarray,
    next_observations: np.ndarray,
    terminals: np.ndarray,
    timeouts: np.ndarray,
) -> dict[str, np.ndarray]:
    """Arrays for ``d3rlpy.dataset.MDPDataset`` whose transitions are exactly the given ones.

    Each episode that ends by a timeout gets one extra row: its final next observation, a zero
    action and reward, and the timeout flag (moved from its last real step). d3rlpy does not make
    a transition of an episode's last row unless it is terminal, so the extra row only supplies the
    next observation of the real last step. Terminated episodes are passed unchanged (d3rlpy
    pairs their last step with a zero observation, which the terminal flag masks).

    :return: ``observations``, ``actions``, ``rewards`` (``[M, 1]``), ``terminals``, ``timeouts``
        (float32), ``rows`` (``[M]``, index of each row's transition in the input, -1 for extra rows)
    """
    observations = np.asarray(observations, dtype=np.float32)
    next_observations = np.asarray(next_observations, dtype=np.float32)
    actions = np.asarray(actions, dtype=np.float32)
    rewards = np.asarray(rewards, dtype=np.float32).reshape(-1)
    n = len(rewards)
    ends = episode_ends(terminals, timeouts)
    timed_out = np.asarray(timeouts)[ends] > 0
    pad_after = ends[timed_out]  # an extra row after each of these steps
    # position of every input row in the output: shifted by the extra rows inserted before it
    shift = np.searchsorted(pad_after, np.arange(n), side="left")
    pos = np.arange(n) + shift
    pad_pos = pad_after + np.arange(len(pad_after)) + 1
    m = n + len(pad_after)
    out_obs = np.empty((m, *observations.shape[1:]), dtype=np.float32)
    out_act = np.zeros((m, *actions.shape[1:]), dtype=np.float32)
    out_rew = np.zeros((m, 1), dtype=np.float32)
    out_term = np.zeros(m, dtype=np.float32)
    out_timeout = np.zeros(m, dtype=np.float32)
    rows = np.full(m, -1, dtype=np.int64)
    out_obs[pos] = observations
    out_act[pos] = actions
    out_rew[pos, 0] = rewards
    out_term[pos] = np.asarray(terminals, dtype=np.float32)
    rows[pos] = np.arange(n)
    out_obs[pad_pos] = next_observations[pad_after]
    out_timeout[pad_pos] = 1.0
    return {
        "observations": out_obs,
        "actions": out_act,
        "rewards": out_rew,
        "terminals": out_term,
        "timeouts": out_timeout,
        "rows": rows,
    }


def check_alignment(dataset: Any, arrays: dict[str, np.ndarray]) -> int:
    """Check every transition d3rlpy's transition picker makes of ``dataset`` against the exported arrays.

    Transitions are visited in order (episode by episode), so the ``k``-th must be row ``k`` of the
    export: same observation, action, reward and terminal flag, and the dataset's own next
    observation (a zero one on terminal steps, which d3rlpy masks).

    :param dataset: a d3rlpy ``ReplayBuffer`` (``MDPDataset``)
    :param arrays: the exported arrays (:func:`load_npz`)
    :return: the number of transitions checked (all of them)
    """
    picker = dataset.transition_picker
    k = 0
    n = len(arrays["rewards"])
    for episode in dataset.episodes:
        for i in range(episode.transition_count):
            if k >= n:
                raise AssertionError(f"d3rlpy makes more transitions than the {n} exported")
            t = picker(episode, i)
            terminal = float(arrays["terminals"][k]) > 0
            expected_next = np.zeros_like(arrays["next_observations"][k]) if terminal else arrays["next_observations"][k]
            if not (
                np.array_equal(t.observation, arrays["observations"][k])
                and np.array_equal(t.action, arrays["actions"][k])
                and float(np.asarray(t.reward).reshape(-1)[0]) == float(arrays["rewards"][k])
                and float(t.terminal) == float(terminal)
                and np.array_equal(t.next_observation, expected_next)
            ):
                raise AssertionError(f"d3rlpy's transition {k} (episode step {i}) differs from the exported transition {k}")
            k += 1
    if k != n:
        raise AssertionError(f"d3rlpy makes {k} transitions of the {n} exported")
    return k


# ----------------------------------------------------------------------------------------- d3rlpy


def hyperparameters(algo: str, steps: int) -> dict[str, Any]:
    """The d3rlpy settings of each baseline: d3rlpy's defaults, plus what its reproduction scripts add.

    - TD3+BC: ``reproductions/offline/td3_plus_bc.py`` (the paper's alpha 2.5, states standardised);
    - IQL: ``reproductions/offline/iql.py`` (rewards scaled by 1000 / (max - min episode return),
      actor learning rate cosine-annealed over the run: ``T_max`` is our step budget);
    - BC: ``BCConfig()`` as it is (deterministic policy, mean squared error).
    """
    if algo == "td3bc":
        return {
            "actor_learning_rate": 3e-4,
            "critic_learning_rate": 3e-4,
            "batch_size": 256,
            "gamma": 0.99,
            "tau": 0.005,
            "n_critics": 2,
            "target_smoothing_sigma": 0.2,
            "target_smoothing_clip": 0.5,
            "alpha": 2.5,
            "update_actor_interval": 2,
            "observation_scaler": "StandardObservationScaler()",
        }
    if algo == "iql":
        return {
            "actor_learning_rate": 3e-4,
            "critic_learning_rate": 3e-4,
            "batch_size": 256,
            "gamma": 0.99,
            "tau": 0.005,
            "n_critics": 2,
            "expectile": 0.7,
            "weight_temp": 3.0,
            "max_weight": 100.0,
            "reward_scaler": "ReturnBasedRewardScaler(multiplier=1000.0)",
            "actor_lr_schedule": f"CosineAnnealingLR(T_max={steps})",
        }
    if algo == "bc":
        return {"batch_size": 100, "learning_rate": 1e-3, "policy_type": "deterministic"}
    raise ValueError(f"unknown algorithm {algo!r}: one of {', '.join(VARIANT_NAMES)}")


def make_algo(algo: str, steps: int, device: str = "cpu:0") -> Any:
    """The d3rlpy algorithm of :func:`hyperparameters`."""
    import d3rlpy

    hp = hyperparameters(algo, steps)
    if algo == "td3bc":
        kwargs = {k: v for k, v in hp.items() if k != "observation_scaler"}
        return d3rlpy.algos.TD3PlusBCConfig(
            **kwargs, observation_scaler=d3rlpy.preprocessing.StandardObservationScaler()
        ).create(device=device)
    if algo == "iql":
        kwargs = {k: v for k, v in hp.items() if k not in ("reward_scaler", "actor_lr_schedule")}
        return d3rlpy.algos.IQLConfig(
            **kwargs,
            actor_optim_factory=d3rlpy.optimizers.AdamFactory(
                lr_scheduler_factory=d3rlpy.optimizers.CosineAnnealingLRFactory(T_max=steps)
            ),
            reward_scaler=d3rlpy.preprocessing.ReturnBasedRewardScaler(multiplier=1000.0),
        ).create(device=device)
    return d3rlpy.algos.BCConfig(**hp).create(device=device)


def build_dataset(arrays: dict[str, np.ndarray]) -> Any:
    """A d3rlpy ``MDPDataset`` of the exported transitions (see :func:`prepare_episode_arrays`)."""
    import d3rlpy

    prepared = prepare_episode_arrays(*(arrays[name] for name in TRANSITION_FIELDS))
    return d3rlpy.dataset.MDPDataset(
        observations=prepared["observations"],
        actions=prepared["actions"],
        rewards=prepared["rewards"],
        terminals=prepared["terminals"],
        timeouts=prepared["timeouts"],
        action_space=d3rlpy.ActionSpace.CONTINUOUS,
        action_size=int(arrays["actions"].shape[1]),
    )


def make_env(meta: dict[str, Any]) -> Any:
    """The dataset's environment (its id, time limit and keyword arguments from the export).

    Ids Gymnasium does not know (the point mazes) are registered from ``gymnasium_robotics``. Dict
    observations are flattened by Gymnasium's ``FlattenObservation``, in the space's key order, which must
    be the export's ``dict_keys`` (the order of the arrays the baselines trained on).

    :raises ValueError: the env's dict keys differ from the export's, or a flat env for dict data
    """
    import gymnasium as gym

    if meta["env_id"] not in gym.registry:
        import gymnasium_robotics

        gym.register_envs(gymnasium_robotics)
    kwargs = json.loads(meta.get("env_kwargs") or "{}")
    env = gym.make(meta["env_id"], max_episode_steps=meta.get("max_episode_steps"), **kwargs)
    keys = json.loads(meta.get("dict_keys") or "[]")
    space = env.observation_space
    env_keys = list(space.spaces) if isinstance(space, gym.spaces.Dict) else []
    if env_keys != keys:
        raise ValueError(f"{meta['env_id']} observes the dict keys {env_keys}; the exported data was flattened from {keys}")
    return gym.wrappers.FlattenObservation(env) if keys else env


def unscale_action(action: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """[-1, 1] -> the env's bounds (clipped to [-1, 1] first, as the policies' tanh already is)."""
    return low + 0.5 * (np.clip(action, -1.0, 1.0) + 1.0) * (high - low)


def evaluate(
    algo: Any,
    env: Any,
    n_episodes: int,
    seed: int,
    low: np.ndarray,
    high: np.ndarray,
    successes: list[bool | None] | None = None,
) -> np.ndarray:
    """Returns of ``n_episodes`` deterministic episodes; episode ``i`` is reset with ``seed + i`` (score's protocol).

    ``successes`` (a list) receives per episode whether a step's ``info["success"]`` / ``info["is_success"]`` was
    true, or ``None`` when the env reports none (as score's ``evaluate``).
    """
    returns = np.zeros(n_episodes)
    for i in range(n_episodes):
        obs, _ = env.reset(seed=seed + i)
        done, success = False, None
        while not done:
            action = algo.predict(np.asarray(obs, dtype=np.float32)[None])[0]
            obs, reward, terminated, truncated, info = env.step(
                unscale_action(action, low, high).astype(env.action_space.dtype)
            )
            returns[i] += float(reward)
            done = bool(terminated or truncated)
            success = update_success(success, info)
        if successes is not None:
            successes.append(success)
    return returns


def _load_scores_module() -> Any:
    """``sb3_pola/common/metrics.py`` (NumPy only), loaded by its path: this venv cannot import ``sb3_pola`` itself."""
    path = pathlib.Path(__file__).resolve().parents[1] / "common" / "metrics.py"
    spec = importlib.util.spec_from_file_location("_sb3_pola_scores", path)
    assert spec is not None and spec.loader is not None, f"no {path}"
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# per-episode D4RL scores (NaN without reference scores) and the success rate: the package's one implementation
_scores = _load_scores_module()
normalized_scores, update_success, success_rate = _scores.normalized_scores, _scores.update_success, _scores.success_rate
CSV_FIELDS = _scores.EVALUATION_FIELDS  # peers.csv: the columns of score's scores.csv
evaluation_seed = _scores.evaluation_seed


def eval_row(
    algo: Any, env: Any, meta: dict[str, Any], dataset_id: str, variant: str, seed: int, step: int, episodes: int
) -> dict[str, Any]:
    """One evaluation as a CSV row (``wall_s`` left to the caller): reset seeds ``10_000 * (seed + 1) + i``, as score's."""
    successes: list[bool | None] = []
    returns = evaluate(algo, env, episodes, evaluation_seed(seed), meta["action_low"], meta["action_high"], successes)
    scores = normalized_scores(returns, meta.get("ref_min_score"), meta.get("ref_max_score"))
    rate = success_rate(successes)
    return {
        "dataset": dataset_id,
        "variant": variant,
        "seed": seed,
        "step": step,
        "score": round(float(np.mean(scores)), 3),
        "score_std": round(float(np.std(scores)), 3),
        "mean_return": round(float(np.mean(returns)), 2),
        "eval_episodes": episodes,
        "success": float("nan") if rate is None else round(rate, 3),
    }


def drop_rows(csv_path: pathlib.Path, dataset: str, variant: str, seed: int, after_step: int = 0) -> int:
    """Remove a cell's rows of steps above ``after_step`` from the CSV (atomically); returns how many."""
    if not csv_path.exists():
        return 0
    with csv_path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    kept = [
        r
        for r in rows
        if (r["dataset"], r["variant"], int(r["seed"])) != (dataset, variant, seed) or int(r["step"]) <= after_step
    ]
    if len(kept) != len(rows):
        tmp = csv_path.with_suffix(".tmp")
        with tmp.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=CSV_FIELDS)
            writer.writeheader()
            writer.writerows({k: r.get(k) or "nan" for k in CSV_FIELDS} for r in kept)  # success: new column
        tmp.replace(csv_path)
    return len(rows) - len(kept)


def append_row(csv_path: pathlib.Path, row: dict[str, Any]) -> None:
    if csv_path.exists() and csv_path.stat().st_size > 0:
        with csv_path.open(newline="") as f:
            header = next(csv.reader(f), [])
        if header != CSV_FIELDS:  # a file from before the success column: rewrite it with the column
            with csv_path.open(newline="") as f:
                rows = list(csv.DictReader(f))
            with csv_path.open("w", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=CSV_FIELDS)
                writer.writeheader()
                writer.writerows({k: r.get(k) or "nan" for k in CSV_FIELDS} for r in rows)
    new = not csv_path.exists() or csv_path.stat().st_size == 0
    with csv_path.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_FIELDS)
        if new:
            writer.writeheader()
        writer.writerow({k: row.get(k, "nan") for k in CSV_FIELDS})
        f.flush()


def versions() -> dict[str, str]:
    """Versions of the libraries this worker runs with."""
    import d3rlpy
    import gymnasium
    import torch

    info = {"d3rlpy": d3rlpy.__version__, "torch": torch.__version__, "gymnasium": gymnasium.__version__}
    info["numpy"] = np.__version__
    try:
        import mujoco

        info["mujoco"] = mujoco.__version__
    except ImportError:
        pass
    info["python"] = sys.version.split()[0]
    return info


def random_states() -> dict[str, Any]:
    """The states of the generators d3rlpy draws from (numpy's global one samples the minibatches)."""
    import torch

    numpy_state = np.random.get_state()  # noqa: NPY002 (d3rlpy samples from numpy's legacy global generator)
    return {"python": random.getstate(), "numpy": numpy_state, "torch": torch.get_rng_state().numpy()}


def set_random_states(states: dict[str, Any]) -> None:
    import torch

    random.setstate(states["python"])
    np.random.set_state(states["numpy"])  # noqa: NPY002
    torch.set_rng_state(torch.from_numpy(states["torch"]))


def save_checkpoint(path: pathlib.Path, algo: Any, run_key: dict[str, Any], step: int, wall_s: float) -> None:
    """Model and optimiser states (d3rlpy's ``save_model``), gradient step and random states, written atomically."""
    buffer = io.BytesIO()
    algo.impl.save_model(buffer)
    state = {
        "run": run_key,
        "step": step,
        "grad_step": int(algo.grad_step),
        "wall_s": wall_s,
        "model": buffer.getvalue(),
        "random": random_states(),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    with tmp.open("wb") as f:
        pickle.dump(state, f)
    tmp.replace(path)


def load_checkpoint(path: pathlib.Path, run_key: dict[str, Any]) -> dict[str, Any] | None:
    """The checkpoint of this very run (same algorithm, seed, budget and dataset), else None."""
    if not path.is_file():
        return None
    try:
        with path.open("rb") as f:
            state = pickle.load(f)  # our own file, written by save_checkpoint
    except (OSError, pickle.UnpicklingError, EOFError) as error:
        print(f"[peers] unreadable checkpoint {path} ({error}): starting again", flush=True)
        return None
    if state.get("run") != run_key:
        print(f"[peers] checkpoint {path} is of another run ({state.get('run')}): starting again", flush=True)
        return None
    return state


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Train one (dataset, algorithm, seed) cell, appending an evaluation row to ``--csv`` every ``--eval-freq`` steps."""
    import d3rlpy
    import torch

    torch.set_num_threads(args.threads)
    meta = load_npz(args.npz)
    dataset_id = args.dataset or meta["dataset_id"]
    variant = VARIANT_NAMES[args.algo]
    dataset = build_dataset(meta)
    n_checked = check_alignment(dataset, meta)
    print(f"[peers] {dataset_id}: {n_checked} transitions in {len(dataset.episodes)} episodes, aligned with the export")
    d3rlpy.seed(args.seed)
    algo = make_algo(args.algo, args.steps)
    env = make_env(meta)
    csv_path = pathlib.Path(args.csv)
    ckpt = pathlib.Path(args.ckpt) if args.ckpt else None
    run_key = {k: getattr(args, k) for k in ("algo", "seed", "steps", "eval_freq", "eval_episodes")}
    run_key["dataset"] = dataset_id
    state = load_checkpoint(ckpt, run_key) if ckpt is not None else None
    done, previous_wall = 0, 0.0
    if state is not None:
        from d3rlpy.algos.utility import build_scalers_with_transition_picker

        build_scalers_with_transition_picker(algo, dataset)
        algo.build_with_dataset(dataset)
        algo.impl.load_model(io.BytesIO(state["model"]))
        algo.set_grad_step(state["grad_step"])
        done, previous_wall = int(state["step"]), float(state["wall_s"])
        print(f"[peers] {dataset_id} {variant} seed {args.seed}: resuming from step {done}", flush=True)
    dropped = drop_rows(csv_path, dataset_id, variant, args.seed, after_step=done)
    if dropped:
        print(f"[peers] {dataset_id} {variant} seed {args.seed}: dropped {dropped} rows of an interrupted run", flush=True)
    if state is not None:  # after everything that draws random numbers while building
        set_random_states(state["random"])
    start = time.perf_counter()

    def callback(algo: Any, epoch: int, total_step: int) -> None:
        step = done + total_step
        if step % args.eval_freq != 0 and step != args.steps:
            return
        row = eval_row(algo, env, meta, dataset_id, variant, args.seed, step, args.eval_episodes)
        row["wall_s"] = round(previous_wall + time.perf_counter() - start, 1)
        append_row(csv_path, row)
        if ckpt is not None and step < args.steps:
            save_checkpoint(ckpt, algo, run_key, step, row["wall_s"])
        print(f"[peers] {dataset_id} {variant} seed {args.seed} step {step}: score {row['score']:.1f} ", end="")
        print(f"(return {row['mean_return']:.0f}), {row['wall_s']:.0f}s", flush=True)

    remaining = args.steps - done
    if remaining > 0:
        algo.fit(
            dataset,
            n_steps=remaining,
            n_steps_per_epoch=remaining,
            show_progress=False,
            save_interval=remaining + 1,
            logger_adapter=d3rlpy.logging.NoopAdapterFactory(),
            callback=callback,
        )
    env.close()
    if ckpt is not None:
        ckpt.unlink(missing_ok=True)
    return {
        "dataset": dataset_id,
        "variant": variant,
        "algo": args.algo,
        "seed": args.seed,
        "steps": args.steps,
        "eval_freq": args.eval_freq,
        "eval_episodes": args.eval_episodes,
        "wall_s": round(previous_wall + time.perf_counter() - start, 1),
        "resumed_from": done,
        "transitions": n_checked,
        "hyperparameters": hyperparameters(args.algo, args.steps),
        "versions": versions(),
    }


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description="One d3rlpy baseline cell of sb3-pola peers.")
    parser.add_argument("--npz", help="dataset exported by sb3_pola.grid.peers")
    parser.add_argument("--algo", choices=list(VARIANT_NAMES), default="td3bc")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", type=int, default=10_000)
    parser.add_argument("--eval-freq", type=int, default=2_000)
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--csv", help="CSV the evaluation rows are appended to")
    parser.add_argument("--dataset", help="dataset id written in the rows (default: the export's)")
    parser.add_argument("--result", help="JSON file written at the end (hyperparameters, versions, wall time)")
    parser.add_argument("--ckpt", help="checkpoint file, saved at every evaluation and resumed from (removed at the end)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    parser.add_argument("--versions", action="store_true", help="print the library versions as JSON and exit")
    args = parser.parse_args(argv)
    if not args.versions and (args.npz is None or args.csv is None):
        parser.error("--npz and --csv are required")
    if args.steps < 1 or args.eval_freq < 1 or args.eval_episodes < 1:
        parser.error("--steps, --eval-freq and --eval-episodes must be positive")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.versions:
        print(json.dumps(versions()))
        return 0
    result = run(args)
    if args.result:
        path = pathlib.Path(args.result)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(result, indent=1))
        tmp.replace(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
