"""Where ``sb3-pola score`` keeps its outputs: a local folder, or any storage fsspec reads (``s3://``, ``gs://``, ...).

The score code reads and writes files in a local folder. With a plain path that folder is the storage
itself and nothing is copied, so a run into a folder behaves as it always did. With an fsspec URL
(``s3://bucket/run`` with s3fs installed, ``gs://`` with gcsfs, ``file:///shared/run``, ...) the code works
in a local scratch folder, a :class:`Workspace`: it pulls the files it needs from the :class:`Storage`
first and pushes the files it changed back. Every push is atomic (an upload to a temp name, then a move),
so a process killed mid-upload leaves the previous version of the file, never a truncated one, and a
resume from the storage is as exact as a resume from a folder.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import pathlib
import shutil
import tempfile
import uuid
from collections.abc import Iterator
from typing import TYPE_CHECKING

from sb3_pola.common.checkpoint import write_atomically

if TYPE_CHECKING:
    from fsspec import AbstractFileSystem


def is_url(location: str | os.PathLike) -> bool:
    """Whether ``location`` is an fsspec URL (``protocol://...``) rather than a folder path."""
    return "://" in str(location)


class Storage:
    """Files under a root of an fsspec filesystem, addressed by paths relative to the root (``ckpt/a.zip``).

    :param url: an fsspec URL (``s3://bucket/run``, ``file:///shared/run``, ``memory://run``); the backend of
        its protocol must be installed (``ImportError`` otherwise, ``ValueError`` for an unknown protocol)
    """

    def __init__(self, url: str) -> None:
        from fsspec.core import url_to_fs

        self.url = url
        self.fs: AbstractFileSystem
        self.fs, root = url_to_fs(url)
        self.root = root.rstrip("/")

    def _path(self, rel: str) -> str:
        return f"{self.root}/{rel}" if rel else self.root

    def exists(self, rel: str) -> bool:
        """Whether the file ``rel`` exists."""
        return bool(self.fs.isfile(self._path(rel)))

    def get(self, rel: str, local: pathlib.Path) -> bool:
        """Download ``rel`` to ``local`` (atomically, its folder made); ``False`` if there is no such file."""
        try:
            write_atomically(local, lambda tmp: self.fs.get_file(self._path(rel), str(tmp)))
        except FileNotFoundError:
            return False
        return True

    def put(self, local: pathlib.Path, rel: str) -> None:
        """Upload ``local`` to ``rel`` atomically: to a temp name next to it, then moved over it.

        A kill mid-upload leaves a temp file (``.<name>.<random>.tmp``, skipped by :meth:`list`) and the
        previous version of ``rel``.
        """
        path = self._path(rel)
        parent, name = path.rsplit("/", 1)
        self.fs.makedirs(parent, exist_ok=True)  # object stores have no folders: a no-op there
        tmp = f"{parent}/.{name}.{uuid.uuid4().hex}.tmp"
        try:
            self.fs.put_file(str(local), tmp)
            self.fs.mv(tmp, path)
        except BaseException:
            with contextlib.suppress(Exception):  # best effort: a killed process leaves the temp file anyway
                self.fs.rm_file(tmp)
            raise

    def list(self, rel: str) -> list[str]:
        """The files under the folder ``rel`` (recursively, sorted), relative to the root; temp files left out."""
        base = self._path(rel)
        if not self.fs.isdir(base):
            return []
        found = []
        for path in self.fs.find(base):
            name = path.rsplit("/", 1)[-1]
            if not (name.startswith(".") and name.endswith(".tmp")):
                found.append(path[len(self.root) + 1 :])
        return sorted(found)

    def remove(self, rel: str) -> None:
        """Delete the file ``rel`` (nothing if it does not exist)."""
        with contextlib.suppress(FileNotFoundError):
            self.fs.rm_file(self._path(rel))


class Workspace:
    """A local folder to work in, standing for a storage: the storage itself, or a scratch copy of part of it.

    Files are named by a string relative to the folder (``"ckpt/a.zip"``) or a ``pathlib.Path`` inside it.
    Without a storage every method but :meth:`exists` and :meth:`remove` does nothing: the folder is the storage.

    :param folder: the local folder
    :param storage: the storage it stands for (``None``: the folder itself)
    """

    def __init__(self, folder: pathlib.Path, storage: Storage | None = None) -> None:
        self.folder = folder
        self.storage = storage
        # digest of every file as last pulled or pushed: what a push need not upload again (a content digest, as
        # a file rewritten in place within one tick of the clock keeps its mtime, and often its size)
        self._synced: dict[str, bytes] = {}

    def shown(self, rel: str = "") -> str:
        """How a file of the storage is named in messages: its path, or its URL."""
        if self.storage is None:
            return str(self.folder / rel)
        return f"{self.storage.url.rstrip('/')}/{rel}" if rel else self.storage.url

    @property
    def location(self) -> str:
        """What another process opens the same storage with (:func:`open_workspace`)."""
        return self.storage.url if self.storage is not None else str(self.folder.resolve())

    def _rel(self, path: str | pathlib.Path) -> str:
        if isinstance(path, pathlib.Path):  # a path inside the folder (relative if the folder's path is)
            path = path.relative_to(self.folder)
        return pathlib.PurePath(path).as_posix()

    def _digest(self, rel: str) -> bytes | None:
        digest = hashlib.blake2b()
        try:
            with (self.folder / rel).open("rb") as file:
                while chunk := file.read(1 << 20):
                    digest.update(chunk)
        except FileNotFoundError:
            return None
        return digest.digest()

    def exists(self, path: str | pathlib.Path) -> bool:
        """Whether the file exists in the storage."""
        rel = self._rel(path)
        return self.storage.exists(rel) if self.storage is not None else (self.folder / rel).is_file()

    def pull(self, *paths: str | pathlib.Path) -> None:
        """Download these files (those that exist in the storage) into the folder, replacing local copies."""
        if self.storage is None:
            return
        for rel in map(self._rel, paths):
            if self.storage.get(rel, self.folder / rel):
                self._synced[rel] = self._digest(rel) or b""

    def pull_tree(self, path: str | pathlib.Path) -> None:
        """Download every file under a folder of the storage."""
        if self.storage is not None:
            self.pull(*self.storage.list(self._rel(path)))

    def push(self, *paths: str | pathlib.Path) -> None:
        """Upload, in this order, those of these files that exist locally and changed since their last pull or push."""
        if self.storage is None:
            return
        for rel in map(self._rel, paths):
            digest = self._digest(rel)
            if digest is not None and digest != self._synced.get(rel):
                self.storage.put(self.folder / rel, rel)
                self._synced[rel] = digest

    def push_tree(self, path: str | pathlib.Path, pattern: str = "*") -> None:
        """Upload the changed files under a local folder (those matching ``pattern``, recursively)."""
        folder = self.folder / self._rel(path)
        if self.storage is not None and folder.is_dir():
            self.push(*sorted(p for p in folder.rglob(pattern) if p.is_file()))

    def remove(self, path: str | pathlib.Path) -> None:
        """Delete a file from the storage (not from the scratch folder)."""
        rel = self._rel(path)
        if self.storage is not None:
            self.storage.remove(rel)
        else:
            (self.folder / rel).unlink(missing_ok=True)


@contextlib.contextmanager
def open_workspace(location: str | os.PathLike) -> Iterator[Workspace]:
    """The workspace of an output location: a folder path (made if missing) or an fsspec URL (a scratch folder).

    :param location: a folder path, or an fsspec URL
    :return: a context manager yielding the workspace; a scratch folder is deleted at its end
    """
    if not is_url(location):
        folder = pathlib.Path(location)
        folder.mkdir(parents=True, exist_ok=True)
        yield Workspace(folder)
        return
    storage = Storage(str(location))
    scratch = pathlib.Path(tempfile.mkdtemp(prefix="sb3-pola-"))
    try:
        yield Workspace(scratch, storage)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
