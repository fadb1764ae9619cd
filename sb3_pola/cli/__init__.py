"""``sb3-pola`` command line: one sub-command per tool, each in a module of its own.

:func:`main` is the one place that turns the user's errors into one line on stderr and exit status 2, without a
traceback (``--debug`` or ``SB3_POLA_DEBUG=1`` prints it too): the package's
:class:`~sb3_pola.common.errors.UserError` (datasets not found or corrupt, model files, bad arguments and
hyperparameters, export refusals) and missing extras. Commands that need an optional extra (``setup.py``'s
``extras_require``) say which one: :mod:`sb3_pola.common.extras` is the one place that knows this.
"""

from __future__ import annotations

import importlib
import os
import pathlib
import sys
import traceback

from sb3_pola.common.errors import UserError
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


def version() -> str:
    """The package's version, read without importing torch."""
    return (pathlib.Path(__file__).resolve().parent.parent / "version.txt").read_text().strip()


def debug_requested(argv: list[str]) -> bool:
    """``--debug`` among the arguments or ``SB3_POLA_DEBUG`` set (not to 0): show tracebacks of user errors."""
    return "--debug" in argv or os.environ.get("SB3_POLA_DEBUG", "0") not in ("", "0")


def report(command: str, error: BaseException, debug: bool) -> int:
    """Print a user error as one line (after its traceback with ``debug``).

    :param command: the sub-command
    :param error: the error
    :param debug: print the traceback first
    :return: exit status 2
    """
    if debug:
        traceback.print_exception(error)
    message = " ".join(str(error).split())  # one line, whatever the message holds
    print(f"sb3-pola {command}: error: {message}" + ("" if debug else " (--debug shows the traceback)"), file=sys.stderr)
    return 2


def usage() -> str:
    lines = ["usage: sb3-pola [--version] [--debug] <command> [args]", "", "commands:"]
    for name, (_, help_) in COMMANDS.items():
        extras = COMMAND_EXTRAS.get(name, ())
        lines.append(f"  {name:<11} {help_}" + (f" [extra: {', '.join(extras)}]" if extras else ""))
    lines += [
        "",
        f"extras: {install_hint('<extra>')}; `sb3-pola <command> --help` for a command's options",
        "--debug (or SB3_POLA_DEBUG=1): show the traceback of an error, not only its one line",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Dispatch ``argv`` to a sub-command's ``main``.

    :param argv: ``[command, *arguments]`` (default: ``sys.argv[1:]``)
    :return: exit status (2 for an unknown command, a user error or a missing extra)
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = debug_requested(argv)
    argv = [arg for arg in argv if arg != "--debug"]
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0
    if argv[0] in ("-V", "--version"):
        print(f"sb3-pola {version()}")
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
    except UserError as error:
        return report(name, error, debug)
    except ImportError as error:  # also the commands' own errors raised from a ModuleNotFoundError
        extra = missing_extra(name, error)
        if extra is None:
            raise
        if debug:
            traceback.print_exception(error)
        print(missing_extra_message(name, extra, error), file=sys.stderr)
        return 2
    return int(result or 0)


if __name__ == "__main__":
    sys.exit(main())
