"""``sb3-pola`` command line: one sub-command per tool, each module owning its own arguments."""

from __future__ import annotations

import importlib
import sys

# sub-command -> (module with a ``main(argv)``, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("sb3_pola.experiments.run", "train POLA on a dataset, evaluate it, print a table (the main job)"),
    "collect": ("sb3_pola.collect", "record D4RL-style Minari datasets for a Gymnasium env"),
    "train": ("sb3_pola.zoo", "rl-zoo3 train with POLA registered"),
    "enjoy": ("sb3_pola.zoo", "rl-zoo3 enjoy with POLA registered"),
    "optimize": ("sb3_pola.zoo", "rl-zoo3 hyperparameter search with POLA's sampler"),
    "bench": ("sb3_pola.benchmarks.bench", "speed and memory benchmarks"),
    "score": ("sb3_pola.experiments.score", "score benchmark: POLA and its ablations over datasets and seeds"),
    "peers": ("sb3_pola.experiments.peers", "d3rlpy baselines (TD3+BC, IQL, BC) for the score table"),
    "model-check": ("sb3_pola.experiments.model_check", "k-step error of the dynamics model under dataset and policy actions"),
    "datasets": ("sb3_pola.common.datasets", "list the Minari datasets found locally"),
    "export": ("sb3_pola.pola.export", "export a saved model's deterministic policy to ONNX or TorchScript"),
}


def usage() -> str:
    lines = ["usage: sb3-pola <command> [args]", "", "commands:"]
    lines += [f"  {name:<10} {help_}" for name, (_, help_) in COMMANDS.items()]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"sb3-pola: unknown command {name!r}\n\n{usage()}", file=sys.stderr)
        return 2
    module = importlib.import_module(COMMANDS[name][0])
    if COMMANDS[name][0] == "sb3_pola.zoo":
        rest = [name, *rest]
    result = module.main(rest)
    return int(result or 0)


if __name__ == "__main__":
    sys.exit(main())
