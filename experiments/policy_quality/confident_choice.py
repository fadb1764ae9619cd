"""#23: would POLA do better to act as BC where its critic is not sure its own action is better? An offline screen on
saved models, no training.

    MINARI_DATASETS_PATH=<data> python experiments/policy_quality/confident_choice.py --dataset hopper/medium-v0 \\
        --seed 0 --pola OUT/hopper_medium-v0/RNW/seed0.zip --bc OUT/hopper_medium-v0/BCRNW/seed0.zip --k 0 1 2 \\
        [--out rows.jsonl]
    MINARI_DATASETS_PATH=<data> python experiments/policy_quality/confident_choice.py --dataset hopper/medium-v0 \
        --seed 0 --model OUT/hopper_medium-v0/FB1/seed0.zip --k pola bc 0 1 2 [--out rows.jsonl]

At every state of the evaluation both models act under the package's rule (``predict(obs, deterministic=True)``) and
POLA's critic ensemble judges the two actions member by member: ``d_j = Q_j(s, a_pola) - Q_j(s, a_bc)``. POLA's action
is taken where ``mean_j d_j > k std_j d_j`` (a one-sided test over the members at ``k``), BC's elsewhere; ``k = 0`` is
the argmax of the ensemble's mean over the two. 10 episodes on the score protocol's resets (as ``screen.py``: reset
seed ``10000 (seed + 1) + i``) for each ``--k``; one JSON row per call (score, share of steps on POLA's action, the
mazes' success rate), printed and appended to ``--out``.

``--model`` evaluates one model trained with the package's option (``policy_kwargs={"fallback_confidence": k}``:
both actors in one model, the rule inside ``predict``) at each ``--k``; ``pola`` and ``bc`` are its own actor alone
and its imitation actor alone (the rule at a ``k`` no gain reaches either way), so one model gives the paired
comparison. With ``--model`` the row also holds, at each numeric ``k``, the share of ``--data-states`` states drawn
from the data (seed 0) on which the rule takes the model's own action (``k<k>_data_share``): what the critic says of
the two actors before any evaluation.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np
import torch as th

from sb3_pola import POLA
from sb3_pola.common.datasets import load_offline_dataset, make_env
from sb3_pola.common.evaluation import evaluate
from sb3_pola.pola.policies import choose_confident


class ConfidentChoice:
    """``predict`` of the choice between two models' actions (the interface :func:`evaluate` calls)."""

    def __init__(self, pola: POLA, bc: POLA, k: float) -> None:
        self.pola, self.bc, self.k = pola, bc, k
        self.took_pola: list[bool] = []

    def predict(self, obs: Any, deterministic: bool = True) -> tuple[np.ndarray, None]:
        a_pola, _ = self.pola.predict(obs, deterministic=True)
        a_bc, _ = self.bc.predict(obs, deterministic=True)
        state, _ = self.pola.policy.obs_to_tensor(obs)  # [1, obs_dim]
        actions = th.as_tensor(np.stack([a_pola, a_bc]), dtype=th.float32).reshape(2, 1, -1)  # [2, 1, act_dim]
        with th.no_grad():
            q = self.pola.policy.critic(state.expand(2, -1), actions.flatten(0, 1))  # [N, 2]
        take = bool(th.equal(choose_confident(q, actions[0], actions[1], self.k), actions[0]))
        self.took_pola.append(take)
        return (a_pola if take else a_bc), None


class ModelChoice:
    """``predict`` of a model with a fallback actor at another ``k``, counting the steps on POLA's action."""

    def __init__(self, model: POLA, k: float) -> None:
        self.model, self.k = model, k
        self.took_pola: list[bool] = []
        policy = model.policy
        choose = type(policy).confident_choice

        def counted(obs: th.Tensor, action: th.Tensor, fallback: th.Tensor, k: float) -> th.Tensor:
            chosen = choose(policy, obs, action, fallback, k)
            self.took_pola.extend((chosen == action).all(dim=1).tolist())
            return chosen

        policy.confident_choice = counted  # type: ignore[method-assign]

    def predict(self, obs: Any, deterministic: bool = True) -> tuple[np.ndarray, None]:
        self.model.policy.fallback_confidence = self.k
        return self.model.predict(obs, deterministic=True)


# the model's own actor alone and its imitation actor alone: a k below or above every gain
EXTREMES = {"pola": -1e9, "bc": 1e9}


def data_share(model: POLA, observations: np.ndarray, k: float) -> float:
    """The share of ``observations`` ``[n, obs]`` on which the model's confident choice at ``k`` takes its own
    action (both actors under the policy's deterministic rule)."""
    policy = model.policy
    assert policy.fallback_actor_ema is not None
    obs = th.as_tensor(observations, dtype=th.float32)
    policy.set_training_mode(False)
    with th.no_grad():
        own = policy._actor_action(policy.actor_ema, obs, deterministic=True)
        fallback = policy._actor_action(policy.fallback_actor_ema, obs, deterministic=True)
        chosen = type(policy).confident_choice(policy, obs, own, fallback, k)
    return float(np.mean((chosen == own).all(dim=1).numpy()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--seed", type=int, required=True, help="the models' training seed (sets the resets)")
    parser.add_argument("--pola", help="the POLA model's file")
    parser.add_argument("--bc", help="the BC model's file (the package's actor, eta = 0)")
    parser.add_argument("--model", help="instead of --pola and --bc: a model with the package's fallback actor")
    parser.add_argument("--k", nargs="+", default=["0", "1", "2"], help="numbers; with --model also pola, bc")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--data-states", type=int, default=2000, help="with --model: data states for the data share")
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    th.set_num_threads(1)
    if (args.model is None) == (args.pola is None or args.bc is None):
        parser.error("give --model, or --pola and --bc")
    data = load_offline_dataset(args.dataset)
    env = make_env(data)
    row: dict[str, Any] = {"dataset": args.dataset, "seed": args.seed}
    if args.model is not None:
        model = POLA.load(args.model, device="cpu")
        if model.policy.fallback_actor is None:
            parser.error(f"{args.model} has no fallback actor (policy_kwargs fallback_confidence)")
        row["model"] = args.model
        rows = np.random.default_rng(0).choice(len(data.observations), args.data_states, replace=False)
        for k in args.k:
            if k not in EXTREMES:
                row[f"k{float(k):g}_data_share"] = round(data_share(model, data.observations[rows], float(k)), 3)
    else:
        pola, bc = POLA.load(args.pola, device="cpu"), POLA.load(args.bc, device="cpu")
    for k in args.k:
        name = k if k in EXTREMES else f"k{float(k):g}"
        value = EXTREMES[k] if k in EXTREMES else float(k)
        choice = ModelChoice(model, value) if args.model is not None else ConfidentChoice(pola, bc, value)
        successes: list[Any] = []
        returns = evaluate(choice, env, args.episodes, 10_000 * (args.seed + 1), True, successes)
        score = data.normalized_score(returns)
        row[name] = round(score if score is not None else float(returns.mean()), 1)
        row[f"{name}_pola_share"] = round(float(np.mean(choice.took_pola)), 3)
        if successes and successes[0] is not None:
            row[f"{name}_success"] = round(float(np.mean([bool(s) for s in successes])), 2)
    print(json.dumps(row), flush=True)
    if args.out:
        with open(args.out, "a") as f:
            f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
