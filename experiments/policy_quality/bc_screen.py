"""Issue #23's imitation screen: held-out action MSE of actor variants after N steps of behaviour cloning.

Trains each variant on the first 90% of a dataset's transitions (whole episodes, in recording order) and
measures the mean squared error of its action on the last 10% (up to 5,000 rows): the noise-free chain
(``mse_det``) and one sample (``mse_sample``). With ``--episodes N`` it also plays the trained actor (the noise-free
chain; an MSE regressor's output) for N episodes on the score protocol's resets (``score``, normalised where the
dataset has reference scores). One JSON line per variant on stdout.

    python experiments/policy_quality/bc_screen.py --dataset halfcheetah/medium-v0 [--variants mse eps x0 ...] \
        [--episodes 10 [--eval-every 2000]]

The ``mse-d3rlpy`` variant is d3rlpy's BC network in this loop (2 x 256, ReLU, states as recorded, no products,
lr 1e-3): it separates what the regressor's loss does from what the package's inputs do.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th
from torch import nn
from torch.nn import functional as F

from sb3_pola.common.datasets import OfflineDataset, load_offline_dataset, make_env
from sb3_pola.common.evaluation import episode_returns
from sb3_pola.common.torch_layers import StateProductsExtractor
from sb3_pola.pola.fast_sampling import sample_no_grad
from sb3_pola.pola.pola import _lerp_params
from sb3_pola.pola.policies import DiffusionActor

# name -> what departs from: the diffusion actor, 2 x 128, lr 3e-4, 5 steps, state products, constant lr
VARIANTS: dict[str, dict[str, Any]] = {
    "mse": {"kind": "mse"},
    "eps": {"prediction_type": "epsilon"},
    "x0": {"prediction_type": "sample"},
    "eps-lr1e-3": {"prediction_type": "epsilon", "lr": 1e-3},
    "x0-lr1e-3": {"prediction_type": "sample", "lr": 1e-3},
    "x0-256-lr1e-3": {"prediction_type": "sample", "lr": 1e-3, "arch": [256, 256]},
    "mse-256-lr1e-3": {"kind": "mse", "lr": 1e-3, "arch": [256, 256]},
    "x0-cos": {"prediction_type": "sample", "cosine": True},
    "x0-lr1e-3-cos": {"prediction_type": "sample", "lr": 1e-3, "cosine": True},
    "x0-noprod": {"prediction_type": "sample", "products": False},
    "x0-lr1e-3-noprod": {"prediction_type": "sample", "lr": 1e-3, "products": False},
    "x0-10steps": {"prediction_type": "sample", "n_steps": 10},
    "mse-lr1e-3": {"kind": "mse", "lr": 1e-3},
    "mse-lr1e-3-noprod": {"kind": "mse", "lr": 1e-3, "products": False},
    "mse-d3rlpy": {"kind": "mse", "lr": 1e-3, "arch": [256, 256], "products": False, "relu": True, "raw": True},
    "x0-lr1e-3-raw": {"prediction_type": "sample", "lr": 1e-3, "raw": True},
    "x0-256-lr1e-3-relu-raw-noprod": {
        "prediction_type": "sample",
        "lr": 1e-3,
        "arch": [256, 256],
        "products": False,
        "relu": True,
        "raw": True,
    },
}
# the same with the package's weight average of the actor (ema_decay 0.995)
VARIANTS |= {f"{name}-ema": {**VARIANTS[name], "ema": 0.995} for name in ("mse-d3rlpy", "x0-lr1e-3")}
# d3rlpy BC's network pieces one at a time on the package's diffusion actor (``x0-lr1e-3`` plus the piece; the width,
# raw states and no products have rows above), and d3rlpy's network under the diffusion loss less one piece
D3RLPY_PIECES: dict[str, dict[str, Any]] = {
    "256": {"arch": [256, 256]},
    "relu": {"relu": True},
    "raw": {"raw": True},
    "noprod": {"products": False},
}
VARIANTS["x0-lr1e-3-relu"] = {"prediction_type": "sample", "lr": 1e-3, "relu": True}
# the two pieces whose removal from d3rlpy's network costs the U-maze (twenty-seventh pass), with the package's
# width and state normalisation, with and without the weight average
VARIANTS["x0-lr1e-3-relu-noprod"] = {"prediction_type": "sample", "lr": 1e-3, "relu": True, "products": False}
VARIANTS["x0-lr1e-3-relu-noprod-ema"] = {**VARIANTS["x0-lr1e-3-relu-noprod"], "ema": 0.995}
VARIANTS |= {
    f"x0-d3rlpy-but-{left_out}": {
        "prediction_type": "sample",
        "lr": 1e-3,
        **{k: v for piece, cfg in D3RLPY_PIECES.items() if piece != left_out for k, v in cfg.items()},
    }
    for left_out in D3RLPY_PIECES
}


def build(cfg: dict[str, Any], extractor: StateProductsExtractor, act_dim: int) -> tuple[nn.Module, Callable, Callable]:
    """The network, its loss ``(obs, actions) -> loss`` and its action ``(obs, deterministic) -> actions``."""
    if cfg.get("kind") == "mse":
        layers: list[nn.Module] = []
        width = extractor.features_dim
        for hidden in cfg["arch"]:
            layers += [nn.Linear(width, hidden), nn.ReLU() if cfg.get("relu") else nn.Mish()]
            width = hidden
        mlp = nn.Sequential(*layers, nn.Linear(width, act_dim), nn.Tanh())
        return mlp, lambda o, a: F.mse_loss(mlp(extractor(o)), a), lambda o, det: mlp(extractor(o))
    kind = cfg["prediction_type"]
    activation = nn.ReLU if cfg.get("relu") else nn.Mish
    actor = DiffusionActor(
        extractor.features_dim, act_dim, cfg["arch"], cfg["n_steps"], prediction_type=kind, activation_fn=activation
    )

    def act(obs: th.Tensor, deterministic: bool) -> th.Tensor:
        generator = th.Generator().manual_seed(123)
        return sample_no_grad(actor, extractor(obs), generator=generator, deterministic=deterministic)

    return actor, lambda o, a: actor.loss(a, extractor(o)), act


class Ema:
    """The package's weight average of the actor (``POLA._update``: a copy until ``ema_start`` = 1000, then ``ema_decay``
    every ``ema_update_freq`` = 5 steps, through the same ``_lerp_params``); :meth:`swap` exchanges the network's
    weights with the average's, for an evaluation and back."""

    def __init__(self, net: nn.Module, decay: float) -> None:
        self.net, self.decay = net, decay
        self.average = [p.detach().clone() for p in net.parameters()]

    def update(self, step: int) -> None:
        if step % 5 == 0:
            _lerp_params(self.net.parameters(), self.average, 1.0 - (self.decay if step >= 1000 else 0.0))

    def swap(self) -> None:
        for param, average in zip(self.net.parameters(), self.average, strict=True):
            param.data, average.data = average.data, param.data


def play(data: OfflineDataset, act: Callable, episodes: int, seed: int) -> float:
    """The score of ``act``'s noise-free action over ``episodes`` episodes on the score protocol's resets."""
    env = make_env(data)

    def policy(obs: np.ndarray) -> np.ndarray:
        with th.no_grad():
            return act(th.as_tensor(obs, dtype=th.float32)[None], True)[0].numpy()

    returns = episode_returns(env, policy, episodes, 10_000 * (seed + 1), [])
    score = data.normalized_score(returns)
    return round(score if score is not None else float(returns.mean()), 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--steps", type=int, default=10_000)
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--batch-size", type=int, default=128)
    parser.add_argument("--episodes", type=int, default=0, help="episodes of the trained actor (0: none)")
    parser.add_argument("--eval-every", type=int, default=0, help="with --episodes, also play every N steps")
    args = parser.parse_args()
    th.set_num_threads(1)
    data = load_offline_dataset(args.dataset)
    n_test = len(data) // 10
    obs, actions = th.as_tensor(data.observations), th.as_tensor(data.actions)
    train_obs, train_act = obs[:-n_test], actions[:-n_test]
    test_obs, test_act = obs[-n_test:][:5000], actions[-n_test:][:5000]
    mean, std = train_obs.mean(0), train_obs.std(0).clamp_min(1e-3)
    for name in args.variants:
        cfg = {"lr": 3e-4, "arch": [128, 128], "products": True, "n_steps": 5, **VARIANTS[name]}
        th.manual_seed(args.seed)
        extractor = StateProductsExtractor(data.observation_space, use_state_products=cfg["products"])
        if cfg.get("raw"):  # the states as recorded, as d3rlpy's BC sees them
            extractor.set_normalization(th.zeros_like(mean), th.ones_like(std))
        else:
            extractor.set_normalization(mean, std)
        net, loss_fn, act = build(cfg, extractor, actions.shape[1])
        optimizer = th.optim.Adam(net.parameters(), lr=cfg["lr"])
        scheduler = th.optim.lr_scheduler.CosineAnnealingLR(optimizer, args.steps) if cfg.get("cosine") else None
        generator = th.Generator().manual_seed(args.seed)
        ema = Ema(net, cfg["ema"]) if "ema" in cfg else None
        start = time.time()
        curve: list[float] = []
        for step in range(1, args.steps + 1):
            idx = th.randint(0, len(train_obs), (args.batch_size,), generator=generator)
            loss = loss_fn(train_obs[idx], train_act[idx])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            if scheduler is not None:
                scheduler.step()
            if ema is not None:
                ema.update(step)
            if args.episodes and args.eval_every and step % args.eval_every == 0 and step < args.steps:
                if ema is not None:
                    ema.swap()
                curve.append(play(data, act, args.episodes, args.seed))
                if ema is not None:
                    ema.swap()
        if ema is not None:  # everything below measures the average
            ema.swap()
        with th.no_grad():
            mse_det = F.mse_loss(act(test_obs, True), test_act).item()
            mse_sample = F.mse_loss(act(test_obs, False), test_act).item()
        row = {"dataset": args.dataset, "variant": name, "seed": args.seed, "steps": args.steps}
        row.update(mse_det=round(mse_det, 4), mse_sample=round(mse_sample, 4), s=round(time.time() - start, 1))
        if args.episodes:
            row["score"] = play(data, act, args.episodes, args.seed)
            if curve:
                row["scores"] = [*curve, row["score"]]
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
