"""Record D4RL-style Minari datasets for a continuous-action Gymnasium env (``sb3-pola collect``).

Kinds (as in D4RL):

- ``random``: uniform random actions;
- ``medium``: a "medium" policy acting stochastically (``--policy``, or SAC stopped early);
- ``expert``: an expert policy acting stochastically (``--expert-policy``, or the best SAC checkpoint);
- ``medium-replay``: SAC's replay buffer up to the medium checkpoint;
- ``medium-expert``: the medium and expert datasets concatenated.

Several kinds can be made from one SAC run (``--kind medium medium-replay``). The datasets get
``ref_min_score`` (random policy) and ``ref_max_score`` (expert policy, deterministic), each the
mean return over ``--ref-episodes`` (>= 10) episodes. Written with
``minari.create_dataset_from_buffers`` (``DataCollector`` needs jax) under ``--out`` or
``$MINARI_DATASETS_PATH`` as ``<envname>/<kind>-v<version>``.

Gymnasium-Robotics point mazes (``--env PointMaze_UMaze-v3`` etc.) have their own kinds and
options: :mod:`sb3_pola.collect.maze` (``sb3-pola collect --env PointMaze_UMaze-v3 --help``).

Example::

    sb3-pola collect --env InvertedPendulum-v5 --kind medium medium-replay --steps 30000 \\
        --medium-return 250 --medium-max-return 600 --expert-return 1000 --seed 0 --out sb3_pola/data/datasets
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import dataclasses
import json
import pathlib
import sys
import time
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_pola.collect.episodes import PolicyFn, evaluate, policy_fn, progress_bar, rollout
from sb3_pola.collect.writer import MIN_REF_EPISODES, dataset_summary, datasets_root, default_name, write_dataset
from sb3_pola.common.arguments import ArgumentParser
from sb3_pola.common.datasets import D4RL_KINDS

KINDS = D4RL_KINDS


@dataclass
class Checkpoint:
    """A SAC snapshot taken at an evaluation."""

    step: int
    mean_return: float
    policy_state: dict[str, Any]
    replay_pos: int


def load_policy(path: str, algo: str, env: gym.Env) -> Any:
    """Load an SB3 model zip (``algo`` names its class)."""
    import stable_baselines3 as sb3

    algos: dict[str, Any] = {name: getattr(sb3, name.upper()) for name in ("sac", "td3", "ddpg", "ppo", "a2c")}
    with contextlib.suppress(ImportError):
        import sb3_contrib

        algos.update(tqc=sb3_contrib.TQC, trpo=sb3_contrib.TRPO)
    if algo not in algos:
        raise ValueError(f"Unknown --policy-algo {algo!r}; choose from {sorted(algos)}")
    return algos[algo].load(path, env=env, device="cpu")


def train_sac(
    env_id: str,
    train_steps: int,
    seed: int,
    eval_freq: int,
    eval_episodes: int,
    expert_return: float | None,
    progress: bool,
    sac_kwargs: dict[str, Any] | None = None,
) -> tuple[Any, list[Checkpoint]]:
    """Train SAC, snapshotting the policy (and replay-buffer position) at every evaluation.

    :param expert_return: stop once a deterministic evaluation reaches this return
    :return: the model (its replay buffer holds all transitions) and the checkpoints
    """
    from stable_baselines3 import SAC
    from stable_baselines3.common.callbacks import BaseCallback

    eval_env = gym.make(env_id)
    checkpoints: list[Checkpoint] = []

    class EvalSnapshots(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.bar: Any = None

        def _on_training_start(self) -> None:
            self.bar = progress_bar(train_steps, f"SAC {env_id}", progress)

        def _on_training_end(self) -> None:
            self.bar.close()

        def _on_step(self) -> bool:
            self.bar.update(1)
            if self.num_timesteps % eval_freq != 0:
                return True
            returns = evaluate(eval_env, policy_fn(self.model, True), eval_episodes, seed=10_000 + self.num_timesteps)
            mean = float(np.mean(returns))
            replay_buffer = getattr(self.model, "replay_buffer", None)
            assert replay_buffer is not None
            checkpoints.append(
                Checkpoint(
                    self.num_timesteps,
                    mean,
                    copy.deepcopy(self.model.policy.state_dict()),
                    int(replay_buffer.pos),
                )
            )
            self.bar.set_postfix(eval_return=f"{mean:.1f}")
            return expert_return is None or mean < expert_return

    env = gym.make(env_id)
    kwargs = {"buffer_size": max(train_steps, 1), **(sac_kwargs or {})}
    model = SAC("MlpPolicy", env, seed=seed, verbose=0, device="cpu", **kwargs)
    model.learn(total_timesteps=train_steps, callback=EvalSnapshots())
    return model, checkpoints


def pick_medium(checkpoints: list[Checkpoint], low: float | None, high: float | None) -> Checkpoint:
    """First checkpoint whose eval return lies in ``[low, high]``, else the closest one.

    Without ``low``, the target is a third of the best return (D4RL's "medium" level).
    """
    best = max(c.mean_return for c in checkpoints)
    low = best / 3.0 if low is None else low
    high = np.inf if high is None else high
    for checkpoint in checkpoints:
        if low <= checkpoint.mean_return <= high:
            return checkpoint
    target = low if np.isinf(high) else 0.5 * (low + high)
    closest = min(checkpoints, key=lambda c: abs(c.mean_return - target))
    print(
        f"warning: no checkpoint with eval return in [{low}, {high}]; using step {closest.step} "
        f"(return {closest.mean_return:.1f})",
        file=sys.stderr,
    )
    return closest


def replay_episodes(model: Any, end: int) -> list[Any]:
    """Episodes of the SAC replay buffer's first ``end`` transitions (actions in env units)."""
    from minari.data_collector import EpisodeBuffer

    buffer = model.replay_buffer
    obs = buffer.observations[:end, 0]
    next_obs = buffer.next_observations[:end, 0]
    # SAC stores actions scaled to [-1, 1]; the dataset records what the env received.
    actions = model.policy.unscale_action(buffer.actions[:end, 0]).astype(np.float32)
    rewards = buffer.rewards[:end, 0]
    timeouts = buffer.timeouts[:end, 0].astype(bool)
    dones = buffer.dones[:end, 0].astype(bool)
    ends = np.flatnonzero(dones)
    if len(ends) == 0 or ends[-1] != end - 1:
        ends = np.append(ends, end - 1)
    episodes: list[Any] = []
    start = 0
    for stop in (ends + 1).tolist():
        terminations = dones[start:stop] & ~timeouts[start:stop]
        truncations = timeouts[start:stop].copy()
        if not terminations[-1]:
            truncations[-1] = True  # the budget cut the last episode
        episodes.append(
            EpisodeBuffer(
                id=len(episodes),
                observations=np.concatenate([obs[start:stop], next_obs[stop - 1 : stop]]),
                actions=actions[start:stop],
                rewards=rewards[start:stop],
                terminations=terminations,
                truncations=truncations,
            )
        )
        start = stop
    return episodes


def make_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(
        prog="sb3-pola collect",
        description=__doc__.split("\n\n")[0],
        epilog="Point mazes have their own kinds and options: sb3-pola collect --env PointMaze_UMaze-v3 --help",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--env", required=True, help="Gymnasium env id with continuous actions, e.g. InvertedPendulum-v5")
    parser.add_argument("--kind", nargs="+", choices=KINDS, default=["medium"], help="dataset kind(s) to make")
    parser.add_argument("--steps", type=int, default=100_000, help="transitions per dataset (medium-expert: per half)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="datasets root (default $MINARI_DATASETS_PATH or ~/.minari/datasets)")
    parser.add_argument("--name", default=None, help="dataset id prefix (default: env name in lower case)")
    parser.add_argument("--version", type=int, default=0, help="dataset version suffix -v<N>")
    parser.add_argument("--policy", default=None, help="SB3 zip of the medium policy (else trained with SAC)")
    parser.add_argument("--expert-policy", default=None, help="SB3 zip of the expert policy (else trained with SAC)")
    parser.add_argument("--policy-algo", default="sac", help="SB3 class of the policy zips (sac, td3, ddpg, ppo, tqc...)")
    parser.add_argument("--train-steps", type=int, default=100_000, help="SAC step budget")
    parser.add_argument("--medium-return", type=float, default=None, help="medium = first checkpoint with eval return >= this")
    parser.add_argument("--medium-max-return", type=float, default=None, help="... and <= this")
    parser.add_argument("--expert-return", type=float, default=None, help="stop SAC once its eval return reaches this")
    parser.add_argument("--eval-freq", type=int, default=1000, help="SAC evaluation/checkpoint period (env steps)")
    parser.add_argument("--eval-episodes", type=int, default=5)
    parser.add_argument("--learning-starts", type=int, default=None, help="SAC learning_starts (default SB3's)")
    parser.add_argument("--ref-episodes", type=int, default=MIN_REF_EPISODES, help="episodes for each reference score")
    parser.add_argument("--ref-min-score", type=float, default=None, help="override the random-policy reference")
    parser.add_argument("--ref-max-score", type=float, default=None, help="override the expert-policy reference")
    parser.add_argument("--deterministic", action="store_true", help="policies act deterministically while recording")
    parser.add_argument("--save-policies", default=None, help="folder to save the medium/expert policy zips in")
    parser.add_argument("--overwrite", action="store_true", help="replace existing datasets")
    parser.add_argument("--no-progress", action="store_true")
    return parser


@dataclass
class PolicySources:
    """Where the recorded actions come from: the SAC run made here (if any) and the medium / expert policies.

    :param sac: the SAC model trained here, or None
    :param medium_ckpt: its medium checkpoint
    :param expert_ckpt: its best checkpoint
    :param medium_model: the medium SB3 model (given zip or SAC snapshot)
    :param expert_model: the expert SB3 model
    :param medium: the medium policy as recorded (``--deterministic`` or not)
    :param expert: the expert policy as recorded
    :param expert_eval: the expert policy acting deterministically (for ``ref_max_score``)
    """

    sac: Any = None
    medium_ckpt: Checkpoint | None = None
    expert_ckpt: Checkpoint | None = None
    medium_model: Any = None
    expert_model: Any = None
    medium: PolicyFn | None = None
    expert: PolicyFn | None = None
    expert_eval: PolicyFn | None = None


def _needs(args: argparse.Namespace, kinds: list[str]) -> tuple[bool, bool, bool]:
    """Which policies the kinds need, and whether SAC must be trained for them.

    :param args: the parsed arguments
    :param kinds: the dataset kinds to make
    :return: ``(needs_medium, needs_expert, needs_sac)``; the expert is needed for its data or for ``ref_max_score``
    """
    needs_medium = any(k in ("medium", "medium-replay", "medium-expert") for k in kinds)
    needs_expert_data = any(k in ("expert", "medium-expert") for k in kinds)
    needs_expert = args.ref_max_score is None or needs_expert_data
    needs_sac = (needs_medium and args.policy is None) or (needs_expert and args.expert_policy is None)
    return needs_medium, needs_expert, needs_sac or "medium-replay" in kinds


def _train_sac_sources(args: argparse.Namespace, progress: bool, sources: PolicySources, summary: dict[str, Any]) -> bool:
    """Train SAC and pick its medium and expert checkpoints into ``sources`` (noted in ``summary``).

    :param args: the parsed arguments
    :param progress: show progress bars
    :param sources: filled in place
    :param summary: the run's summary, filled in place
    :return: False (with a message) when the run made no checkpoint
    """
    sac_kwargs = {} if args.learning_starts is None else {"learning_starts": args.learning_starts}
    model, checkpoints = train_sac(
        args.env, args.train_steps, args.seed, args.eval_freq, args.eval_episodes, args.expert_return, progress, sac_kwargs
    )
    if not checkpoints:
        print(f"no SAC checkpoint: --train-steps {args.train_steps} < --eval-freq {args.eval_freq}", file=sys.stderr)
        return False
    sources.sac = model
    summary["sac_steps"] = int(model.num_timesteps)
    summary["checkpoints"] = [(c.step, round(c.mean_return, 1)) for c in checkpoints]
    medium_ckpt = sources.medium_ckpt = pick_medium(checkpoints, args.medium_return, args.medium_max_return)
    expert_ckpt = sources.expert_ckpt = max(checkpoints, key=lambda c: c.mean_return)
    summary["medium_checkpoint"] = {"step": medium_ckpt.step, "eval_return": medium_ckpt.mean_return}
    summary["expert_checkpoint"] = {"step": expert_ckpt.step, "eval_return": expert_ckpt.mean_return}
    return True


def _snapshot(model: Any, checkpoint: Checkpoint | None) -> Any:
    """A copy of the SAC model with the policy weights of ``checkpoint``.

    :param model: the SAC model
    :param checkpoint: the checkpoint
    :return: the copy (the replay buffer is shared, not copied)
    """
    assert model is not None and checkpoint is not None
    clone = copy.copy(model)
    clone.policy = copy.deepcopy(model.policy)
    clone.policy.load_state_dict(checkpoint.policy_state)
    return clone


def _load_policies(
    args: argparse.Namespace, env: gym.Env, sources: PolicySources, needs_medium: bool, needs_expert: bool
) -> None:
    """The medium and expert policies: the given zips, else the SAC snapshots (into ``sources``).

    :param args: the parsed arguments
    :param env: the env (to load the zips)
    :param sources: filled in place
    :param needs_medium: the kinds need the medium policy
    :param needs_expert: the kinds or the references need the expert policy
    """
    if needs_medium:
        sources.medium_model = (
            load_policy(args.policy, args.policy_algo, env) if args.policy else _snapshot(sources.sac, sources.medium_ckpt)
        )
        sources.medium = policy_fn(sources.medium_model, args.deterministic)
    if needs_expert and (args.expert_policy or sources.expert_ckpt is not None):
        sources.expert_model = (
            load_policy(args.expert_policy, args.policy_algo, env)
            if args.expert_policy
            else _snapshot(sources.sac, sources.expert_ckpt)
        )
        sources.expert = policy_fn(sources.expert_model, args.deterministic)
        sources.expert_eval = policy_fn(sources.expert_model, True)
    if args.save_policies:
        folder = pathlib.Path(args.save_policies)
        folder.mkdir(parents=True, exist_ok=True)
        name = args.name or default_name(args.env)
        if needs_medium:
            sources.medium_model.save(folder / f"{name}-medium")
        if sources.expert is not None:
            sources.expert_model.save(folder / f"{name}-expert")


def _reference_scores(args: argparse.Namespace, env: gym.Env, expert_eval: PolicyFn | None) -> tuple[float, float]:
    """``ref_min_score`` (random policy) and ``ref_max_score`` (deterministic expert), unless given.

    :param args: the parsed arguments
    :param env: the env
    :param expert_eval: the deterministic expert policy (needed when ``--ref-max-score`` is not given)
    :return: ``(ref_min, ref_max)``
    """
    ref_min = args.ref_min_score
    if ref_min is None:
        ref_min = float(np.mean(evaluate(env, None, args.ref_episodes, seed=args.seed + 20_000)))
    ref_max = args.ref_max_score
    if ref_max is None:
        assert expert_eval is not None  # no --ref-max-score: the expert is needed, from a zip or SAC
        ref_max = float(np.mean(evaluate(env, expert_eval, args.ref_episodes, seed=args.seed + 30_000)))
    return ref_min, ref_max


def _record_kind(
    kind: str, args: argparse.Namespace, env: gym.Env, sources: PolicySources, dataset_id: str, progress: bool
) -> tuple[list[Any], str, str]:
    """The episodes of one dataset kind, with its ``algorithm`` and ``description`` metadata.

    :param kind: one of :data:`KINDS`
    :param args: the parsed arguments
    :param env: the env
    :param sources: the policies
    :param dataset_id: the dataset id (progress bar labels)
    :param progress: show progress bars
    :return: ``(episodes, algorithm, description)``
    """
    seed = args.seed + 1 + KINDS.index(kind) * 1000
    acting = "deterministic" if args.deterministic else "stochastic"
    medium_ckpt, expert_ckpt = sources.medium_ckpt, sources.expert_ckpt
    if kind == "random":
        episodes = rollout(env, None, args.steps, seed, progress, dataset_id)
        return episodes, "uniform random actions", "uniform random actions"
    if kind == "medium":
        episodes = rollout(env, sources.medium, args.steps, seed, progress, dataset_id)
        algorithm = f"SAC medium (step {medium_ckpt.step})" if medium_ckpt and not args.policy else f"policy {args.policy}"
        return episodes, algorithm, f"medium policy, {acting}"
    if kind == "expert":
        episodes = rollout(env, sources.expert, args.steps, seed, progress, dataset_id)
        algorithm = f"SAC expert (step {expert_ckpt.step})" if expert_ckpt and not args.expert_policy else "expert policy"
        return episodes, algorithm, f"expert policy, {acting}"
    if kind == "medium-replay":
        assert sources.sac is not None and medium_ckpt is not None
        episodes = replay_episodes(sources.sac, medium_ckpt.replay_pos)
        return episodes, f"SAC replay buffer up to step {medium_ckpt.step}", "SAC replay buffer up to medium"
    # medium-expert
    episodes = rollout(env, sources.medium, args.steps, seed, progress, dataset_id + " (medium)")
    more = rollout(env, sources.expert, args.steps, seed + 500, progress, dataset_id + " (expert)")
    episodes += [dataclasses.replace(e, id=len(episodes) + i) for i, e in enumerate(more)]
    return episodes, "medium + expert", f"medium and expert policies concatenated, {acting}"


def main(argv: list[str] | None = None) -> int:
    """``sb3-pola collect`` for a MuJoCo (any continuous-action Gymnasium) env; returns the exit code."""
    args = make_parser().parse_args(argv)
    if args.ref_episodes < MIN_REF_EPISODES:
        print(f"--ref-episodes must be >= {MIN_REF_EPISODES}", file=sys.stderr)
        return 2
    env = gym.make(args.env)
    if not isinstance(env.action_space, gym.spaces.Box):
        print(f"{args.env} has action space {env.action_space}: continuous (Box) actions are needed", file=sys.stderr)
        return 2
    out_root = datasets_root(args.out)
    name = args.name or default_name(args.env)
    kinds = list(dict.fromkeys(args.kind))
    dataset_ids = {kind: f"{name}/{kind}-v{args.version}" for kind in kinds}
    progress = not args.no_progress
    start_time = time.perf_counter()
    summary: dict[str, Any] = {"env": args.env, "seed": args.seed}
    existing = [out_root / d for d in dataset_ids.values() if (out_root / d).exists()]
    if existing and not args.overwrite:
        print(f"{existing[0]} exists: pass --overwrite to replace it", file=sys.stderr)
        return 1

    needs_medium, needs_expert, needs_sac = _needs(args, kinds)
    sources = PolicySources()
    if needs_sac and not _train_sac_sources(args, progress, sources, summary):
        return 2
    _load_policies(args, env, sources, needs_medium, needs_expert)
    ref_min, ref_max = _reference_scores(args, env, sources.expert_eval)
    summary.update(ref_min_score=ref_min, ref_max_score=ref_max, ref_episodes=args.ref_episodes, datasets={})

    for kind, dataset_id in dataset_ids.items():
        episodes, algorithm, description = _record_kind(kind, args, env, sources, dataset_id, progress)
        path = write_dataset(
            out_root,
            dataset_id,
            episodes,
            args.env,
            ref_min,
            ref_max,
            args.ref_episodes,
            algorithm,
            description,
            args.overwrite,
        )
        summary["datasets"][dataset_id] = dataset_summary(path, episodes)
    summary["seconds"] = round(time.perf_counter() - start_time, 1)
    print(json.dumps(summary, indent=2))
    return 0
