"""The errors of the safety checks, and the validation of a model file before SB3's ``load`` reads it.

Kept apart from :mod:`sb3_pola.common.checkpoint` so that the base class
(:mod:`sb3_pola.common.offline_algorithm`) and the checkpoint module both import them without importing each other.
"""

from __future__ import annotations

import json
import os
import pathlib
import zipfile

from sb3_pola.common.errors import UserError


class DivergenceError(FloatingPointError):
    """Training produced NaN or inf in a loss or in the parameters."""


class ModelFileError(UserError, ValueError):
    """A model file is missing a part, truncated, corrupt, or not a model of this algorithm."""


class ModelFileNotFoundError(ModelFileError, FileNotFoundError):
    """No model file at the given path."""


def _ends_with_zip_directory(path: pathlib.Path, size: int) -> bool:
    """Whether the file ends with a zip end-of-central-directory record (and its comment), as a complete zip does."""
    tail_size = min(size, 22 + 65535)
    with open(path, "rb") as file:
        file.seek(size - tail_size)
        tail = file.read(tail_size)
    position = tail.rfind(b"PK\x05\x06")
    while position >= 0:
        if position + 22 <= len(tail):
            comment_length = int.from_bytes(tail[position + 20 : position + 22], "little")
            if position + 22 + comment_length == len(tail):
                return True
        position = tail.rfind(b"PK\x05\x06", 0, position)
    return False


def validate_model_file(path: str | os.PathLike, policy_classes: tuple[type, ...] = (), algorithm_name: str = "") -> dict:
    """Check that ``path`` is a complete SB3 model file of the expected kind, before ``load`` touches it.

    :param path: the file (``.zip`` may be omitted, as with SB3's ``load``)
    :param policy_classes: accepted policy classes (empty: any)
    :param algorithm_name: name used in the messages
    :return: the saved ``data`` (class parameters)
    :raises ModelFileNotFoundError: no such file (a ``FileNotFoundError``)
    :raises ModelFileError: truncated, corrupt, or not a model of this algorithm
    """
    from stable_baselines3.common.save_util import json_to_data

    path = pathlib.Path(path)
    candidates = [path] if path.suffix == ".zip" else [path, path.with_name(path.name + ".zip")]
    found = next((p for p in candidates if p.is_file()), None)
    if found is None:
        raise ModelFileNotFoundError(f"No model file at {' or '.join(map(str, candidates))}")
    what = f"{algorithm_name} model file" if algorithm_name else "model file"
    size = found.stat().st_size
    if not _ends_with_zip_directory(found, size):
        # checked first: a truncated model file can still open as a zip, found inside it (policy.pth is itself a zip)
        raise ModelFileError(
            f"{found} is not a valid {what}: truncated or corrupt zip ({size} bytes; no zip directory at its end)"
        )
    try:
        with zipfile.ZipFile(found) as archive:
            names = archive.namelist()
            missing = [name for name in ("data", "policy.pth") if name not in names]
            if missing:
                raise ModelFileError(
                    f"{found} is a zip file but not a saved {what}: it has no {', '.join(missing)} "
                    f"(members: {', '.join(names[:8]) or 'none'})"
                )
            bad_member = archive.testzip()  # reads every member and checks its CRC
            if bad_member is not None:
                raise ModelFileError(f"{found} is corrupt: member {bad_member!r} fails its CRC check")
            raw = archive.read("data").decode()
    except zipfile.BadZipFile as error:
        raise ModelFileError(f"{found} is not a valid {what}: truncated or corrupt zip ({size} bytes; {error})") from error
    except (EOFError, OSError) as error:  # OSError covers zlib errors of damaged members
        raise ModelFileError(f"{found} is not a valid {what}: unreadable ({error})") from error
    try:
        json.loads(raw)
        data = json_to_data(raw)
    except Exception as error:  # a damaged/foreign "data" member: invalid JSON or an unpicklable entry
        raise ModelFileError(f"{found} is not a valid {what}: its 'data' member cannot be read ({error!r})") from error
    if "observation_space" not in data or "action_space" not in data or "policy_class" not in data:
        raise ModelFileError(f"{found} is not a valid {what}: its data has no spaces or policy class")
    policy_class = data["policy_class"]
    if policy_classes and not (isinstance(policy_class, type) and issubclass(policy_class, policy_classes)):
        name = getattr(policy_class, "__qualname__", repr(policy_class))
        expected = ", ".join(c.__name__ for c in policy_classes)
        raise ModelFileError(
            f"{found} holds a model with policy {name}, not a {algorithm_name or 'model'} model (policy {expected}); "
            "load it with the algorithm class that saved it"
        )
    return data


__all__ = ["DivergenceError", "ModelFileError", "ModelFileNotFoundError", "validate_model_file"]
