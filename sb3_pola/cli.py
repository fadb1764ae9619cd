"""``sb3-pola`` command line: one sub-command per tool, each module owning its own arguments.

Commands that need an optional extra (``setup.py``'s ``extras_require``) say which one when its modules are
missing, instead of a traceback: :data:`COMMAND_EXTRAS` and :data:`EXTRA_MODULES` are the one place that
knows this, and :func:`main` prints :func:`missing_extra_message` and exits with status 2.
"""

from __future__ import annotations

import importlib
import sys

# the distribution name of setup.py, as pip takes it: pip install "sb3_pola[zoo]"
DISTRIBUTION = "sb3_pola"

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

# optional extra -> the top-level modules it installs (setup.py's extras_require; a missing one names the extra)
EXTRA_MODULES: dict[str, frozenset[str]] = {
    "zoo": frozenset({"rl_zoo3", "yaml", "optuna", "requests", "tensorboard", "pandas", "sb3_contrib"}),
    "maze": frozenset({"gymnasium_robotics"}),
    "export": frozenset({"onnx", "onnxscript", "onnxruntime"}),
    "ray": frozenset({"ray"}),
}

# sub-command -> the extras it (or one of its options) needs; commands not listed need none
# (peers installs d3rlpy into a venv of its own)
COMMAND_EXTRAS: dict[str, tuple[str, ...]] = {
    "train": ("zoo",),
    "enjoy": ("zoo",),
    "optimize": ("zoo",),
    "collect": ("maze",),  # --env PointMaze_...
    "score": ("ray",),  # --ray
    "export": ("export",),  # ONNX (TorchScript needs none)
    "bench": ("export",),  # its export section
}


def install_hint(extra: str) -> str:
    """The pip command that installs an extra.

    :param extra: name of the extra in setup.py
    :return: ``pip install "sb3_pola[<extra>]"``
    """
    return f'pip install "{DISTRIBUTION}[{extra}]"'


def _missing_modules(error: BaseException) -> list[str]:
    """Top-level names of the modules whose import failed, along the chain of causes of ``error``."""
    names, seen = [], set()
    current: BaseException | None = error
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        if isinstance(current, ModuleNotFoundError) and current.name:
            names.append(current.name.split(".")[0])
        current = current.__cause__ or current.__context__
    return names


def missing_extra(command: str, error: BaseException) -> str | None:
    """The extra of ``command`` whose missing module caused ``error`` (``None``: not a missing extra).

    :param command: the sub-command (a key of :data:`COMMANDS`)
    :param error: the exception raised while importing or running it
    :return: the name of the extra, or ``None``
    """
    for module in _missing_modules(error):
        for extra in COMMAND_EXTRAS.get(command, ()):
            if module in EXTRA_MODULES[extra]:
                return extra
    return None


def missing_extra_message(command: str, extra: str, error: BaseException | None = None) -> str:
    """What to print when ``command`` lacks ``extra``: the extra, the pip command and the missing module.

    :param command: the sub-command
    :param extra: the missing extra
    :param error: the import error (names the module in the message)
    :return: one line
    """
    modules = _missing_modules(error) if error is not None else []
    detail = f" (missing module {modules[0]!r})" if modules else ""
    return f'sb3-pola {command} needs the "{extra}" extra: {install_hint(extra)}{detail}'


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
