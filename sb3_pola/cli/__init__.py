"""``sb3-pola`` command line: one sub-command per tool, each in a module of its own.

Commands that need an optional extra (``setup.py``'s ``extras_require``) say which one when its modules are
missing, instead of a traceback: :mod:`sb3_pola.common.extras` is the one place that knows this, and :func:`main`
prints :func:`~sb3_pola.common.extras.missing_extra_message` and exits with status 2.
"""

from __future__ import annotations

import importlib
import sys

from sb3_pola.common.extras import COMMAND_EXTRAS, install_hint, missing_extra, missing_extra_message

# sub-command -> (module with a ``main(argv)``, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("sb3_pola.cli.run", "train POLA on a dataset, evaluate it, print a table (the main job)"),
    "collect": ("sb3_pola.collect", "record D4RL-style Minari datasets for a Gymnasium env"),
    "train": ("sb3_pola.zoo", "rl-zoo3 train with POLA registered"),
    "enjoy": ("sb3_pola.zoo", "rl-zoo3 enjoy with POLA registered"),
    "optimize": ("sb3_pola.zoo", "rl-zoo3 hyperparameter search with POLA's sampler"),
    "bench": ("sb3_pola.benchmarks.bench", "speed and memory benchmarks"),
    "score": ("sb3_pola.cli.score", "score benchmark: POLA and its ablations over datasets and seeds"),
    "peers": ("sb3_pola.cli.peers", "d3rlpy baselines (TD3+BC, IQL, BC) for the score table"),
    "model-check": ("sb3_pola.cli.model_check", "k-step error of the dynamics model under dataset and policy actions"),
    "datasets": ("sb3_pola.cli.datasets", "list the Minari datasets found locally"),
    "export": ("sb3_pola.cli.export", "export a saved model's deterministic policy to ONNX or TorchScript"),
}


def usage() -> str:
    lines = ["usage: sb3-pola <command> [args]", "", "commands:"]
    for name, (_, help_) in COMMANDS.items():
        extras = COMMAND_EXTRAS.get(name, ())
        lines.append(f"  {name:<11} {help_}" + (f" [extra: {', '.join(extras)}]" if extras else ""))
    lines += ["", f"extras: {install_hint('<extra>')}; `sb3-pola <command> --help` for a command's options"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Dispatch ``argv`` to a sub-command's ``main``.

    :param argv: ``[command, *arguments]`` (default: ``sys.argv[1:]``)
    :return: exit status (2 for an unknown command or a missing extra)
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"sb3-pola: unknown command {name!r}\n\n{usage()}", file=sys.stderr)
        return 2
    module_name = COMMANDS[name][0]
    if module_name == "sb3_pola.zoo":
        rest = [name, *rest]
    try:
        module = importlib.import_module(module_name)
        result = module.main(rest)
    except ImportError as error:  # also the commands' own errors raised from a ModuleNotFoundError
        extra = missing_extra(name, error)
        if extra is None:
            raise
        print(missing_extra_message(name, extra, error), file=sys.stderr)
        return 2
    return int(result or 0)


if __name__ == "__main__":
    sys.exit(main())
