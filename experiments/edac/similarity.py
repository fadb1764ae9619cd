"""#12: how alike the critics' action gradients are at the data, for saved final models (T=3, seed 0): the 10k
grid's (no similarity term) and the critic-diversity run's. ``python experiments/edac/similarity.py``."""

from __future__ import annotations

import os
import pathlib

import torch as th

from sb3_pola import POLA
from sb3_pola.common.datasets import load_offline_dataset
from sb3_pola.pola.pola import ensemble_similarity

ROOT = pathlib.Path(__file__).resolve().parents[1]
# the recipes' raw outputs (train/, models/): outputs/<run> unless RUNS names another folder
RUNS = pathlib.Path(os.environ.get("RUNS", ROOT.parent / "outputs"))
DATA = pathlib.Path(os.environ["MINARI_DATASETS_PATH"])  # the folder of Minari datasets


def similarity(model: POLA, dataset: str, n: int = 4096) -> float:
    data = load_offline_dataset(DATA / dataset)
    idx = th.randperm(len(data.observations), generator=th.Generator().manual_seed(0))[:n]
    obs = th.as_tensor(data.observations[idx], dtype=th.float32)
    actions = th.as_tensor(data.actions[idx], dtype=th.float32)
    inputs = model.critic.inputs(obs, actions).expand(model.n_critics, -1, -1).clone().requires_grad_(True)
    (grads,) = th.autograd.grad(model.critic.q_values(inputs).sum(), inputs)
    return ensemble_similarity(grads[..., -actions.shape[-1] :]).item()


def main() -> None:
    print("| dataset | critics | similarity of the action gradients at the data (N = 5: all aligned) |")
    print("|---|---|---|")
    for dataset in ("halfcheetah/medium-v0", "halfcheetah/medium-replay-v0"):
        name = f"{dataset.replace('/', '_')}__T3__seed0.zip"
        for label, folder in (("plain (10k grid)", "score10k"), ("critic_diversity 1", "edac/div1.0")):
            path = RUNS / folder / "models" / name
            if path.exists():
                print(f"| {dataset} | {label} | {similarity(POLA.load(path, device='cpu'), dataset):.2f} |")


if __name__ == "__main__":
    main()
