"""#23: the critic and the dynamics model along a trained policy's own evaluation rollouts, next to the data.

The training statistics (``lookahead_diag.py``) look at the data's states; a policy that falls in the env (T = 3 on
hopper/medium after 30,000 steps) acts elsewhere. For each final model of the long runs (``OUT/models``, written by
``run.sh``) this rolls the policy out as the evaluation does (``predict(deterministic=True)``) and prints, over the
visited steps and, as reference, over a sample of the data:

- ``G``: the realised discounted return-to-go (rollout steps whose episode ended, or with at least 300 steps left);
- ``Q``: the ensemble's top-K pessimistic Q at the state and the action taken (the policy loss's Q), and ``Q - G``;
- ``std``: the ensemble's spread there;
- ``err1`` / ``err3``: the dynamics model's 1- and 3-step error on the actions actually taken (RMS over state
  dimensions in the data's standard deviations), and ``u1``: the elites' disagreement on the first step (median /
  95th percentile);
- ``Qs3 - Q3``: Q at the model's third predicted state with the policy acting there, minus Q at the real third state
  (what the look-ahead's last term sees against what the policy will find).

``python experiments/long100k/onpolicy_diag.py --out outputs/long100k --dataset hopper/medium-v0``
"""

from __future__ import annotations

import argparse
import pathlib

import numpy as np
import torch as th

from sb3_pola import POLA
from sb3_pola.common.datasets import load_offline_dataset, make_env
from sb3_pola.pola.losses import pessimistic_q

HORIZON = 3


def rollouts(model: POLA, env, episodes: int, seed: int) -> list[dict[str, np.ndarray]]:
    """Episodes of the policy as the evaluation acts: observations, scaled actions, rewards, next observations."""
    out = []
    for ep in range(episodes):
        obs, _ = env.reset(seed=seed + ep)
        rows: dict[str, list] = {"obs": [], "act": [], "rew": [], "next": []}
        done = terminated = False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            nxt, rew, terminated, truncated, _ = env.step(action)
            rows["obs"].append(obs)
            rows["act"].append(model.policy.scale_action(action))
            rows["rew"].append(rew)
            rows["next"].append(nxt)
            obs, done = nxt, terminated or truncated
        ep_rows = {k: np.asarray(v, dtype=np.float32) for k, v in rows.items()}
        ep_rows["terminated"] = np.asarray(terminated)
        out.append(ep_rows)
    return out


def discounted(rewards: np.ndarray, gamma: float) -> np.ndarray:
    g, acc = np.zeros_like(rewards, dtype=np.float64), 0.0
    for t in range(len(rewards) - 1, -1, -1):
        acc = rewards[t] + gamma * acc
        g[t] = acc
    return g


def act(model: POLA, obs: np.ndarray) -> np.ndarray:
    """The evaluation's actions at a batch of states, scaled to [-1, 1] as the critic and the model take them."""
    return model.policy.scale_action(model.predict(obs, deterministic=True)[0]).astype(np.float32)


def top_k_q(model: POLA, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
    """Eq. 4's pessimistic Q, as the policy loss reads it."""
    return pessimistic_q(model.critic(obs, actions), model.top_k, model.lcb_coef)


@th.no_grad()
def measure(model: POLA, obs: np.ndarray, actions: list[np.ndarray], nxt: list[np.ndarray]) -> dict[str, np.ndarray]:
    """Per-step figures at ``obs[t], actions[0][t]``; ``actions[i]`` / ``nxt[i]`` the action ``i`` steps on and the real
    state after it (nan where the episode has ended)."""
    dyn = model.policy.dynamics
    s, a = th.as_tensor(obs), th.as_tensor(actions[0])
    q = model.critic(s, a)  # [N, B]
    out = {"Q": pessimistic_q(q, model.top_k, model.lcb_coef).numpy(), "std": q.std(dim=0).numpy()}
    if dyn is None:
        return out
    # the model's error on the actions actually taken, open loop
    state = s
    for i in range(HORIZON):
        pred, _, _, u = dyn.step(state, th.as_tensor(actions[i]))
        err = ((pred - th.as_tensor(nxt[i])) / dyn.obs_std).pow(2).mean(dim=-1).sqrt()  # [B], nan past the end
        if i == 0:
            out["err1"], out["u1"] = err.numpy(), u.numpy()
        state = pred
    out["err3"] = err.numpy()
    # what the look-ahead's last term sees (the policy acting in the model) against Q at the real third state
    state = s
    for _ in range(HORIZON):
        state = dyn.step(state, th.as_tensor(act(model, state.numpy())))[0]
    real3 = np.nan_to_num(nxt[HORIZON - 1])
    q_model = top_k_q(model, state, th.as_tensor(act(model, state.numpy())))
    q_real = top_k_q(model, th.as_tensor(real3), th.as_tensor(act(model, real3)))
    gap = (q_model - q_real).numpy()
    gap[np.isnan(nxt[HORIZON - 1]).any(axis=1)] = np.nan
    out["Qs3 - Q3"] = gap
    return out


def shifted(x: np.ndarray, i: int) -> np.ndarray:
    """``x[t + i]`` at row ``t``, nan past the end."""
    return np.concatenate([x[i:], np.full((i, x.shape[1]), np.nan, dtype=x.dtype)]) if i else x


def summarise(name: str, figures: dict[str, np.ndarray], g: np.ndarray, ok: np.ndarray) -> str:
    cols = [f"{np.nanmean(g[ok]):.1f}", f"{np.nanmean(figures['Q'][ok]):.1f}", f"{np.nanmean(figures['Q'][ok] - g[ok]):+.1f}"]
    cols.append(f"{np.nanmean(figures['std'][ok]):.2f}")
    for key in ("err1", "err3", "u1"):  # medians: a few states where the model diverges dominate a mean
        values = figures.get(key)
        cols.append(f"{np.nanmedian(values[ok]):.3g} / {np.nanpercentile(values[ok], 95):.3g}" if values is not None else "-")
    cols.append(f"{np.nanmean(figures['Qs3 - Q3'][ok]):+.1f}" if "Qs3 - Q3" in figures else "-")
    return f"| {name} | " + " | ".join(cols) + " |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="outputs/long100k", help="the long runs' output folder (its models/)")
    parser.add_argument("--dataset", default="hopper/medium-v0")
    parser.add_argument("--variants", nargs="+", default=["T3", "T0", "BC"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--data-sample", type=int, default=5000, help="data transitions measured as reference")
    args = parser.parse_args()
    th.set_num_threads(1)
    data = load_offline_dataset(args.dataset)
    env = make_env(data)
    tag = args.dataset.replace("/", "_")
    print("| model | G | Q | Q - G | std | err1 | err3 | u1 | Qs3 - Q3 |")
    print("|---|---|---|---|---|---|---|---|---|")
    for variant in args.variants:
        for seed in args.seeds:
            path = pathlib.Path(args.out) / "models" / f"{tag}__{variant}__seed{seed}.zip"
            if not path.exists():
                continue
            model = POLA.load(path, device="cpu")
            gamma = model.gamma
            eps = rollouts(model, env, args.episodes, seed=10_000 + seed)
            obs = np.concatenate([e["obs"] for e in eps])
            nxt = [np.concatenate([shifted(e["next"], i) for e in eps]) for i in range(HORIZON)]
            g = np.concatenate([discounted(e["rew"], gamma) for e in eps])
            ok = np.concatenate(
                [np.ones(len(e["rew"]), bool) if e["terminated"] else np.arange(len(e["rew"]))[::-1] >= 300 for e in eps]
            )
            figures = measure(model, obs, [np.concatenate([shifted(e["act"], i) for e in eps]) for i in range(HORIZON)], nxt)
            lengths = [len(e["rew"]) for e in eps]
            print(summarise(f"{variant} s{seed} policy (len {np.mean(lengths):.0f})", figures, g, ok))
            # the same figures at the data (its own actions and next states; returns-to-go from the dataset)
            rng = np.random.default_rng(seed)
            ends = data.episode_ends()
            idx = rng.choice(len(data) - HORIZON, size=args.data_sample, replace=False)
            same_ep = ~ends[idx] & ~ends[idx + 1]  # three transitions of one episode
            idx = idx[same_ep]
            d_nxt = [data.next_observations[idx + i] for i in range(HORIZON)]
            d_fig = measure(model, data.observations[idx], [data.actions[idx + i] for i in range(HORIZON)], d_nxt)
            d_g = data.returns_to_go(gamma)[idx]
            print(summarise(f"{variant} s{seed} data", d_fig, d_g, np.ones(len(idx), bool)))


if __name__ == "__main__":
    main()
