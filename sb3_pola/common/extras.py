"""The optional extras of ``setup.py`` and the ``sb3-pola`` commands that need them: the one place that knows this.

A command whose extra is missing says which one to install (:func:`missing_extra_message`) instead of a
traceback. It imports nothing of the package, so every layer can use it.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import sys
from typing import Any

# the distribution name of setup.py, as pip takes it: pip install "sb3_pola[zoo]"
DISTRIBUTION = "sb3_pola"

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


def import_gymnasium_robotics() -> Any:
    """Import Gymnasium-Robotics (the ``maze`` extra) without the notice its import prints.

    Its ``__init__`` prints a Farama notification about the Adroit hand envs' rewards to stderr, which has nothing to do
    with the point mazes; only that paragraph is dropped, anything else the import writes is passed on.

    :return: the module
    :raises ImportError: it is not installed
    """
    if sys.modules.get("gymnasium_robotics") is not None:
        return sys.modules["gymnasium_robotics"]
    captured = io.StringIO()
    with contextlib.redirect_stderr(captured):
        module = importlib.import_module("gymnasium_robotics")
    text = captured.getvalue()
    try:
        from farama_notifications import notifications

        notice = notifications.get("gymnasium_robotics", {}).get(getattr(module, "__version__", ""))
    except ImportError:
        notice = None
    if notice:
        text = text.replace(notice + "\n", "", 1)
    sys.stderr.write(text)
    return module
