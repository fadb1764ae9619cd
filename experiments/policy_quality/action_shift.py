"""#23: how far saved models' actions move off the data's, and what their own critics think the move is worth.

    MINARI_DATASETS_PATH=<data> python experiments/policy_quality/action_shift.py --dataset hopper/medium-v0 \\
        MODEL.zip [MODEL.zip ...] [--states 2000] [--seed 0]

On ``--states`` states drawn from the dataset (``--seed``), each model's ``predict(obs, deterministic=True)`` (the
package's rule) against the data's action there: the mean squared difference, the mean ``|a|`` and the share of
saturated action dimensions (``|a| > 0.98``), then the model's critic ensemble at both actions: the mean over states
of ``mean_j Q_j(s, pi(s)) - mean_j Q_j(s, a_data)`` (what the Q term bought by the critic's own account) and the
ensemble's standard deviation at each (how sure it is). A gain below the spread is a move the critic cannot tell
from its own noise.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch as th

from sb3_pola import POLA
from sb3_pola.common.datasets import load_offline_dataset


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", required=True)
    parser.add_argument("models", nargs="+")
    parser.add_argument("--states", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    data = load_offline_dataset(args.dataset)
    rows = np.random.default_rng(args.seed).choice(len(data), min(args.states, len(data)), replace=False)
    obs, data_actions = data.observations[rows], data.actions[rows]
    spread, saturated = np.abs(data_actions).mean(), (np.abs(data_actions) > 0.98).mean()
    print(f"{len(rows)} states of {args.dataset}; data: |a| {spread:.3f}, saturated {saturated:.3f}")
    print("| model | action MSE to the data's | mean abs(a) | saturated | critic's gain Q(pi) - Q(data) ", end="")
    print("| ensemble std at pi / at data |")
    print("|---|---|---|---|---|---|")
    for path in args.models:
        model = POLA.load(path, device="cpu")
        actions, _ = model.predict(obs, deterministic=True)
        actions = np.asarray(actions, dtype=np.float32)
        with th.no_grad():
            states = th.as_tensor(obs, dtype=th.float32)
            q_pi = model.policy.critic(states, th.as_tensor(actions))  # [N, B]
            q_data = model.policy.critic(states, th.as_tensor(data_actions, dtype=th.float32))  # [N, B]
        gain = float((q_pi.mean(dim=0) - q_data.mean(dim=0)).mean())
        print(
            f"| {path} | {((actions - data_actions) ** 2).mean():.4f} | {np.abs(actions).mean():.3f} "
            f"| {(np.abs(actions) > 0.98).mean():.3f} | {gain:+.2f} "
            f"| {float(q_pi.std(dim=0).mean()):.2f} / {float(q_data.std(dim=0).mean()):.2f} |"
        )


if __name__ == "__main__":
    main()
