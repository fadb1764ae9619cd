"""Issue #23's return screen: train POLA at the CPU preset's sizes on one dataset and seed, then evaluate the final
model under several rules of ``predict`` (10 episodes each, the score protocol's resets).

    python experiments/policy_quality/screen.py --dataset halfcheetah/medium-v0 --name BC \\
        --kwargs '{"eta": 0.0, "rollout_length": 0}' [--seed 0] [--rules noisefree,obsnoise,sample,best10]

``--kwargs`` is JSON of POLA arguments over the preset's sizes; ``"lr_cos": X`` sets ``learning_rate`` to a cosine
decay from X; ``"policy_kwargs": {"activation_fn": "ReLU"}`` (or ``"actor_activation_fn"``) names a ``torch.nn`` activation and
``"optimizer_class": "AdamW"`` a ``torch.optim`` optimizer (actor and critics). ``--raw-states`` trains on the
states as recorded (the state normalisation set to mean 0, std 1, as d3rlpy's BC sees them; not a package option).
``--actor-layer-norm`` / ``--actor-dropout P`` put a LayerNorm after each hidden linear layer of the actor / a
dropout after each hidden activation (IDQL's actor has both; screens only, not package options; a model made so
loads again only with the same flags). ``--actor-weight-decay WD`` trains the actor alone with
``torch.optim.AdamW(weight_decay=WD)`` (the critics keep Adam). ``--goal-relative`` appends ``(desired_goal -
achieved_goal) / std(desired_goal)`` to the normalised state of goal-conditioned data before the products, in every
network (screens only; loads again only with the flag). ``--eta-after FRACTION ETA`` trains at the kwargs' ``eta``
until that fraction of ``--steps``, then at ``ETA`` (a step in the Q term's weight; screens only).
``--imitation-rows N`` draws the actor's batches (its ``L_d`` and its Q term's states) from the dataset's first N
transitions, the critics' from all: with ``top_episodes.py --keep-all`` the actor learns from the best episodes only
(screens only; the dynamics fit would see those rows only, so give the folder the full dataset's ``dynamics.pt``).
The model is saved in ``OUT/<dataset>/<name>/seed<S>.zip`` (``OUT``: ``outputs/policy_quality``); a second call with the same
name and seed evaluates the saved model (e.g. under another rule). The dynamics model is fitted once per dataset and
reused (``dynamics.pt``). One JSON line per run, appended to ``OUT/screen.jsonl``; ``--episodes`` above 10 adds the
first 10 episodes' score (the protocol's).
"""

from __future__ import annotations

import argparse
import inspect
import json
import pathlib
import re
import time
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.logger import configure

from sb3_pola import POLA
from sb3_pola.common.datasets import load_offline_dataset, make_env
from sb3_pola.common.dict_obs import key_slice
from sb3_pola.common.evaluation import evaluate
from sb3_pola.common.torch_layers import StateProductsExtractor
from sb3_pola.grid.variants import pola_defaults, pola_kwargs
from sb3_pola.pola.actor import DiffusionActor
from sb3_pola.pola.policies import POLAPolicy

# the cpu preset's sizes (sb3-pola score --preset cpu), eager
CPU: dict[str, Any] = {
    "batch_size": 128,
    "n_critics": 5,
    "top_k": 2,
    "dynamics_kwargs": {"n_members": 5, "n_elites": 3, "hidden_dim": 128, "n_layers": 3},
    "dynamics_fit_kwargs": {"max_steps": 2000},
}
# rule -> (n_action_samples, deterministic, deterministic_rule)
RULES = {
    "noisefree": (1, True, "noise_free"),
    "obsnoise": (1, True, "observation_noise"),
    "sample": (1, False, "noise_free"),
    "best10": (10, True, "noise_free"),
    "mode": (1, True, "mode"),
}
# "mode<K>h<bandwidth>", e.g. mode32h0.1: the mode rule with K samples and that kernel bandwidth


def set_rule(policy: POLAPolicy, rule: str) -> bool:
    """Set ``policy`` to evaluate under ``rule`` (a key of ``RULES`` or ``mode<K>h<bandwidth>``); returns
    ``predict``'s ``deterministic``."""
    mode = re.fullmatch(r"mode(\d+)h([\d.]+)", rule)
    if mode:
        policy.mode_samples, policy.mode_bandwidth = int(mode[1]), float(mode[2])
    elif rule == "mode":  # the defaults again, whichever mode<K>h<h> an earlier rule of the list set
        defaults = inspect.signature(POLAPolicy.__init__).parameters
        policy.mode_samples, policy.mode_bandwidth = defaults["mode_samples"].default, defaults["mode_bandwidth"].default
    policy.n_action_samples, deterministic, policy.deterministic_rule = RULES["mode" if mode else rule]
    return deterministic


def patch_actor(layer_norm: bool, dropout: float) -> None:
    """Build every :class:`DiffusionActor` with LayerNorm and/or dropout in its trunk (before the optimizers and
    the EMA copy are made, so both include them)."""
    init = DiffusionActor.__init__

    def patched(self: DiffusionActor, *args: Any, **kwargs: Any) -> None:
        init(self, *args, **kwargs)
        modules = list(self.trunk)
        layers: list[th.nn.Module] = [th.nn.LayerNorm(self.input_layer.out_features)] if layer_norm else []
        for module in modules[:-1]:
            layers.append(module)
            if isinstance(module, th.nn.Linear) and layer_norm:
                layers.append(th.nn.LayerNorm(module.out_features))
            elif not isinstance(module, th.nn.Linear) and dropout > 0:
                layers.append(th.nn.Dropout(dropout))
        self.trunk = th.nn.Sequential(*layers, modules[-1])

    DiffusionActor.__init__ = patched  # type: ignore[method-assign]


def patch_actor_weight_decay(weight_decay: float) -> None:
    """The actor's optimizer becomes ``AdamW(weight_decay=...)`` at the policy's learning rate; the critics' stays."""
    init = POLAPolicy.__init__

    def patched(self: POLAPolicy, *args: Any, **kwargs: Any) -> None:
        init(self, *args, **kwargs)
        lr = self.actor.optimizer.param_groups[0]["lr"]
        self.actor.optimizer = th.optim.AdamW(self.actor.parameters(), lr=lr, weight_decay=weight_decay)

    POLAPolicy.__init__ = patched  # type: ignore[method-assign]


def patch_goal_relative(achieved: slice, desired: slice) -> None:
    """Every :class:`StateProductsExtractor` appends ``(desired - achieved) / std(desired)`` (of the raw flat
    observation) to the normalised state before its products."""

    init_widened = StateProductsExtractor.__init__

    def init(self: StateProductsExtractor, observation_space: Any, use_state_products: bool = True) -> None:
        # the products' indices and feature size of the widened input; the normalisation keeps the raw width
        n = int(np.prod(observation_space.shape))
        widened = gym.spaces.Box(-np.inf, np.inf, (n + desired.stop - desired.start,), np.float32)
        init_widened(self, widened, use_state_products)
        self._observation_space = observation_space
        self.obs_mean = th.zeros(n)
        self.obs_std = th.ones(n)

    def forward(self: StateProductsExtractor, observations: th.Tensor) -> th.Tensor:
        raw = observations.flatten(1).float()
        relative = (raw[:, desired] - raw[:, achieved]) / self.obs_std[desired]
        x = th.cat(((raw - self.obs_mean) / self.obs_std, relative), dim=-1)
        if not self.use_state_products:
            return x
        return th.cat((x, x[:, self.idx_i] * x[:, self.idx_j]), dim=-1)

    StateProductsExtractor.__init__ = init  # type: ignore[method-assign]
    StateProductsExtractor.forward = forward  # type: ignore[method-assign]


def eta_step(before: float, fraction: float, after: float) -> Any:
    """An SB3 schedule of ``eta``: ``before`` until ``fraction`` of training is done, ``after`` from then on."""

    def schedule(progress_remaining: float) -> float:
        return before if 1.0 - progress_remaining < fraction else after

    return schedule


def train_model(
    args: argparse.Namespace,
    data: Any,
    kwargs: dict[str, Any],
    policy_kwargs: dict[str, Any],
    folder: pathlib.Path,
    model_path: pathlib.Path,
) -> POLA:
    """A new model trained for ``--steps`` (the folder's shared dynamics fit loaded if there is one) and saved."""
    model = POLA("MlpPolicy", dataset=data, seed=args.seed, policy_kwargs=policy_kwargs, **kwargs)
    if args.raw_states:
        obs_dim = model.policy.observation_space.shape[0]  # type: ignore[index]
        model.policy.set_normalization(np.zeros(obs_dim), np.ones(obs_dim))
    if args.imitation_rows:  # the critics train on every transition, the actor (L_d and the Q term) on these
        model._n_imitation_rows = args.imitation_rows
    dynamics = folder / "dynamics.pt"
    shared = kwargs.get("dynamics_kwargs") == CPU["dynamics_kwargs"]
    if model.policy.dynamics is not None and shared and dynamics.exists():
        model.policy.dynamics.load_state_dict(th.load(dynamics))
        model.policy.dynamics_fitted.fill_(True)
    # train/ statistics (critic_maturity, q_mean, ...) in OUT/<dataset>/<name>/seed<S>/progress.csv
    model.set_logger(configure(str(folder / args.name / f"seed{args.seed}"), ["csv"]))
    model.learn(args.steps)
    if model.policy.dynamics is not None and shared and not dynamics.exists():
        th.save(model.policy.dynamics.state_dict(), dynamics)
    model.save(model_path)
    return model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--name", required=True)
    parser.add_argument("--kwargs", default="{}")
    parser.add_argument("--steps", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--rules", default="noisefree,obsnoise,sample,best10")
    parser.add_argument("--out", default="outputs/policy_quality")
    parser.add_argument("--raw-states", action="store_true", help="no state normalisation (a new model only)")
    parser.add_argument("--actor-layer-norm", action="store_true", help="LayerNorm in the actor's trunk (a new model)")
    parser.add_argument("--actor-dropout", type=float, default=0.0, help="dropout in the actor's trunk (a new model)")
    parser.add_argument("--actor-weight-decay", type=float, default=0.0, help="the actor's AdamW decay (a new model)")
    parser.add_argument("--goal-relative", action="store_true", help="desired - achieved goal as inputs (mazes)")
    parser.add_argument(
        "--imitation-rows",
        type=int,
        default=0,
        help="the actor's batches from the first N transitions only (top_episodes.py --keep-all; a new model)",
    )
    parser.add_argument("--eta-after", nargs=2, type=float, metavar=("FRACTION", "ETA"), help="eta's value after")
    args = parser.parse_args()
    th.set_num_threads(1)
    if args.actor_layer_norm or args.actor_dropout > 0:
        patch_actor(args.actor_layer_norm, args.actor_dropout)
    if args.actor_weight_decay > 0:
        patch_actor_weight_decay(args.actor_weight_decay)
    kwargs = pola_kwargs({**CPU, **json.loads(args.kwargs)})  # "lr_cos": X, a cosine decay from X, as the grid
    if args.eta_after:
        kwargs["eta"] = eta_step(float(kwargs.get("eta", pola_defaults(["eta"])["eta"])), *args.eta_after)
    policy_kwargs = {"net_arch": [128, 128], **kwargs.pop("policy_kwargs", {})}
    for key in ("activation_fn", "actor_activation_fn"):
        if isinstance(policy_kwargs.get(key), str):
            policy_kwargs[key] = getattr(th.nn, policy_kwargs[key])
    if isinstance(policy_kwargs.get("optimizer_class"), str):
        policy_kwargs["optimizer_class"] = getattr(th.optim, policy_kwargs["optimizer_class"])
    data = load_offline_dataset(args.dataset)
    if args.goal_relative:
        space = data.dict_observation_space
        assert space is not None, "--goal-relative needs goal-conditioned data"
        patch_goal_relative(key_slice(space, "achieved_goal"), key_slice(space, "desired_goal"))
    folder = pathlib.Path(args.out) / args.dataset.replace("/", "_")
    (folder / args.name).mkdir(parents=True, exist_ok=True)
    model_path = folder / args.name / f"seed{args.seed}.zip"
    start = time.time()
    if model_path.exists():
        model = POLA.load(model_path)
    else:
        model = train_model(args, data, kwargs, policy_kwargs, folder, model_path)
    env = make_env(data)
    row: dict[str, Any] = {"dataset": args.dataset, "name": args.name, "seed": args.seed, "steps": args.steps}
    row["episodes"] = args.episodes
    row["train_s"] = round(time.time() - start)
    for rule in args.rules.split(","):
        deterministic = set_rule(model.policy, rule)
        successes: list[bool | None] = []
        returns = evaluate(model, env, args.episodes, 10_000 * (args.seed + 1), deterministic, successes)
        score = data.normalized_score(returns)
        row[rule] = round(score if score is not None else float(returns.mean()), 1)
        if args.episodes > 10:  # the score protocol's 10 episodes are the first 10 resets
            first = data.normalized_score(returns[:10])
            row[rule + "_first10"] = round(first if first is not None else float(returns[:10].mean()), 1)
        if successes and successes[0] is not None:
            row[rule + "_success"] = round(float(np.mean([bool(s) for s in successes])), 2)
    print(json.dumps(row), flush=True)
    with open(pathlib.Path(args.out) / "screen.jsonl", "a") as f:
        f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
