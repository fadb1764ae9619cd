"""The command line's argument parser: errors as one line, defaults shown in ``--help``, docstrings as plain text.

Every ``sb3-pola`` command builds its parser from :class:`ArgumentParser`. A usage error raises
:class:`~sb3_pola.common.errors.UsageError` instead of printing the usage block and exiting, so that the dispatcher
(:func:`sb3_pola.cli.main`) reports it as every other user error: one line on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import json
import re
from collections.abc import Callable
from typing import Any, NoReturn

from sb3_pola.common.errors import UsageError

_ROLE = re.compile(r":[a-z]+:`~?([^`]+)`")


def plain_text(text: str | None) -> str | None:
    """A docstring as the terminal shows it: ````x```` as ```x```, ``:func:`~a.b.c``` as ``c``.

    :param text: reST text
    :return: the plain text
    """
    if text is None:
        return None
    text = _ROLE.sub(lambda match: match.group(1).rsplit(".", 1)[-1], text)
    return text.replace("``", "`")


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """Each option's default after its help; the description's own line breaks kept."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        # no "(default: None)" / "(default: False)": they say nothing
        if action.default in (None, False) or (isinstance(action.default, list) and not action.default):
            return action.help
        return super()._get_help_string(action)


class ArgumentParser(argparse.ArgumentParser):
    """argparse's parser whose errors raise :class:`UsageError` (one line: the error and where to find help)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        kwargs["description"] = plain_text(kwargs.get("description"))
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        raise UsageError(f"{message} (see `{self.prog} --help`)")


def int_at_least(low: int) -> Callable[[str], int]:
    """An argparse ``type``: an integer ``>= low``.

    :param low: the smallest allowed value
    :return: the converter
    """

    def convert(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an int >= {low}, got {text!r}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be an int >= {low}, got {value}")
        return value

    return convert


def json_object(text: str) -> dict[str, Any]:
    """An argparse ``type``: a JSON object (``'{"eta": 0.5}'``).

    :param text: the argument
    :return: the dict
    """
    try:
        value = json.loads(text)
    except json.JSONDecodeError as error:
        raise argparse.ArgumentTypeError(f"not valid JSON ({error.msg} at column {error.colno}): {text!r}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"must be a JSON object such as '{{\"eta\": 0.5}}', got {text!r}")
    return value


__all__ = ["ArgumentParser", "HelpFormatter", "int_at_least", "json_object", "plain_text"]
