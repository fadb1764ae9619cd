"""What several commands share: ``--data-dir`` sets ``MINARI_DATASETS_PATH`` for the command only."""

from __future__ import annotations

import contextlib
import os
import pathlib
from collections.abc import Iterator


@contextlib.contextmanager
def datasets_path(data_dir: str | None) -> Iterator[None]:
    """``MINARI_DATASETS_PATH`` at ``data_dir`` (if given) while the command runs (its workers start), then restored."""
    old = os.environ.get("MINARI_DATASETS_PATH")
    if data_dir:
        os.environ["MINARI_DATASETS_PATH"] = str(pathlib.Path(data_dir).resolve())
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = old
