"""The package's errors that are the user's to fix: the command line prints them as one line, without a traceback.

Kept free of imports, so that the dispatcher (:mod:`sb3_pola.cli`) can catch them without importing torch.
"""

from __future__ import annotations


class UserError(Exception):
    """An error in what the user gave (an argument, a dataset, a model file), whose message says what to do.

    ``sb3-pola`` prints ``sb3-pola <command>: <message>`` on one line and exits with status 2; ``--debug`` (or
    ``SB3_POLA_DEBUG=1``) shows the traceback too.
    """


class HyperparameterError(UserError, ValueError):
    """A constructor argument out of its range; the message names the public argument and the allowed values."""


class UsageError(UserError, ValueError):
    """A command-line argument that cannot be used (out of range, wrong file extension...)."""


__all__ = ["HyperparameterError", "UsageError", "UserError"]
