"""``sb3-pola model-check``: the k-step error of the dynamics model under dataset and policy actions
(:mod:`sb3_pola.grid.model_check`)."""

from __future__ import annotations

import json
import pathlib
import time
from typing import Any

import numpy as np
import torch as th

from sb3_pola.cli.options import datasets_path
from sb3_pola.common.arguments import ArgumentParser, int_at_least
from sb3_pola.common.datasets import load_offline_dataset, make_env
from sb3_pola.common.dynamics import EnsembleDynamics
from sb3_pola.common.dynamics_trainer import DynamicsTrainer
from sb3_pola.grid import model_check
from sb3_pola.pola import POLA


def main(argv: list[str] | None = None) -> int:
    """``sb3-pola model-check``.

    :param argv: command-line arguments (default ``sys.argv[1:]``)
    :return: the exit code
    """
    parser = ArgumentParser(prog="sb3-pola model-check", description=model_check.__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--data-dir", help="folder of the Minari datasets (sets MINARI_DATASETS_PATH)")
    parser.add_argument("--mean-loss", nargs="+", default=["nll", "beta_nll", "mse"])
    parser.add_argument("--dynamics-kwargs", default='{"n_members": 5, "n_elites": 3, "hidden_dim": 128, "n_layers": 3}')
    parser.add_argument(
        "--max-steps", type=int_at_least(1), default=2000, help="cap on the fit's gradient steps (the cpu preset's)"
    )
    parser.add_argument("--horizon", type=int_at_least(1), default=3)
    parser.add_argument("--starts", type=int_at_least(1), default=500, help="held-out start states")
    parser.add_argument("--policy", help="a saved POLA model whose actions drive the simulator rollouts")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", help="write the results as JSON here")
    args = parser.parse_args(argv)
    with datasets_path(args.data_dir):
        data = load_offline_dataset(args.dataset)
    rng = np.random.default_rng(args.seed)
    starts = model_check.chained_starts(data, args.horizon, args.starts, rng)
    # the fit sees every transition; the starts are scored on their k-step chains, which the 1-step fit never targets
    policy_model = None
    if args.policy:
        policy_model = POLA.load(args.policy, device="cpu")
    results: dict[str, Any] = {"dataset": args.dataset, "horizon": args.horizon, "starts": len(starts), "fits": {}}
    for mean_loss in args.mean_loss:
        th.manual_seed(args.seed)
        kwargs = {**json.loads(args.dynamics_kwargs), "mean_loss": mean_loss}
        model = EnsembleDynamics(data.observations.shape[1], data.actions.shape[1], **kwargs)
        start = time.perf_counter()
        info = DynamicsTrainer(model, max_steps=args.max_steps).fit(
            data.observations, data.actions, data.next_observations, data.rewards
        )
        model.freeze()
        entry: dict[str, Any] = {"fit": info, "fit_s": time.perf_counter() - start}
        entry["dataset_actions"] = model_check.open_loop_errors(model, data, starts, args.horizon)
        if policy_model is not None:
            env = make_env(data, monitor=False)  # rollouts set the simulator state: no episode bookkeeping
            entry["policy_actions"] = model_check.policy_rollout_errors(model, policy_model, env, data, starts, args.horizon)
            env.close()
        results["fits"][mean_loss] = entry
        fmt = ", ".join
        line = (
            f"[model-check] {mean_loss}: 1-step holdout mse {info['holdout_mse']:.4f} (no change {info['no_change_mse']:.4f})"
        )
        line += "; dataset actions k-step mse " + fmt(f"{v:.4f}" for v in entry["dataset_actions"]["mse"])
        if policy_model is not None:
            pol = entry["policy_actions"]
            line += "; policy actions k-step mse " + fmt(f"{v:.4f}" for v in pol["mse"])
            line += " (no change " + fmt(f"{v:.4f}" for v in pol["no_change_mse"]) + ")"
            line += f", disagreement {fmt(f'{v:.3f}' for v in pol['disagreement'])}"
            line += f", corr(error, disagreement) at k=T {pol['error_disagreement_corr']:.2f}"
        print(line, flush=True)
    if args.out:
        pathlib.Path(args.out).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
