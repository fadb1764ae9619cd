"""Crash-safe training: atomic checkpoints carrying the RNG state, and exact resume.

A checkpoint is the SB3 zip written by ``model.save`` (policy with the EMA actor, target critics,
dynamics model and its ``dynamics_fitted`` flag, both optimizers, ``num_timesteps``, ``_n_updates``,
``_total_timesteps``, hyperparameters) plus one extra member, ``sb3_pola_rng.pt``, holding the torch
(CPU and CUDA), NumPy and Python RNG states. SB3's ``load`` ignores that member, so a checkpoint is
also an ordinary model file. Files are written atomically: a temp file in the same folder, fsync,
``os.replace``, fsync of the folder; a kill at any moment leaves either the previous checkpoint or
the new one, never a truncated file. Weights with NaN or inf are never written (:class:`DivergenceError`,
defined with :class:`ModelFileError` and :func:`validate_model_file` in :mod:`sb3_pola.common.integrity`).

Usage::

    from sb3_pola import POLA
    from sb3_pola.common.checkpoint import CheckpointCallback, learn_with_checkpoints

    model = learn_with_checkpoints(
        POLA,
        lambda: POLA("MlpPolicy", dataset="mujoco/halfcheetah/medium-v0", seed=0),
        total_timesteps=1_000_000,
        save_path="runs/hc",
        save_freq=10_000,
        load_kwargs=dict(dataset="mujoco/halfcheetah/medium-v0"),
    )

Run the same command again after a crash: it resumes from ``runs/hc/pola_latest.zip`` and ends with
the parameters the uninterrupted run would have had (bit-identical on CPU).

Reproducibility. On CPU, the same seed, dataset, torch version and thread count give identical
parameters, and a resumed run reproduces the uninterrupted one exactly. On GPU, a resumed run restores
the same CUDA RNG state, but the results are reproducible only up to floating-point rounding: cuBLAS
and cuDNN may pick different kernels (and reduction orders) from run to run, and ``index_add``-style
atomics are non-deterministic. ``th.use_deterministic_algorithms(True)`` with
``CUBLAS_WORKSPACE_CONFIG=:4096:8`` removes most of that at some speed cost; results still differ
between GPU models, driver/CUDA versions and between CPU and GPU.
"""

from __future__ import annotations

import contextlib
import io
import os
import pathlib
import random
import tempfile
import zipfile
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import MaybeCallback

from sb3_pola.common.integrity import DivergenceError, ModelFileError, validate_model_file

if TYPE_CHECKING:
    from sb3_pola.common.offline_algorithm import OfflineAlgorithm

RNG_MEMBER = "sb3_pola_rng.pt"  # not ".pth": SB3's load reads every ".pth" member as a state_dict
_FORMAT_VERSION = 1


# --------------------------------------------------------------------------- RNG state


def get_rng_state() -> dict[str, Any]:
    """The global RNG states that training draws from: torch CPU (and CUDA when initialised), NumPy, Python.

    :return: a dict of tensors and plain Python values (loadable with ``th.load(weights_only=True)``)
    """
    _, key, pos, has_gauss, cached_gaussian = np.random.get_state(legacy=True)  # type: ignore[misc]  # noqa: NPY002
    state: dict[str, Any] = {
        "torch": th.get_rng_state(),
        "numpy": {"key": th.from_numpy(np.asarray(key, dtype=np.int64)), "pos": int(pos), "has_gauss": int(has_gauss)},
        "numpy_gauss": float(cached_gaussian),
        "python": list(random.getstate()[1]),
        "python_gauss": random.getstate()[2],
    }
    if th.cuda.is_available() and th.cuda.is_initialized():
        state["cuda"] = th.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict[str, Any]) -> None:
    """Restore the RNG states saved by :func:`get_rng_state`.

    :param state: the dict from :func:`get_rng_state`
    """
    th.set_rng_state(state["torch"].cpu())
    if "cuda" in state and th.cuda.is_available():
        cuda_states = state["cuda"]
        if len(cuda_states) == th.cuda.device_count():
            th.cuda.set_rng_state_all([s.cpu() for s in cuda_states])
        else:  # another GPU count: seed what exists from the saved first device
            th.cuda.set_rng_state(cuda_states[0].cpu())
    numpy_state = state["numpy"]
    np.random.set_state(  # noqa: NPY002 (the legacy global RNG is what user code may draw from)
        (
            "MT19937",
            numpy_state["key"].numpy().astype(np.uint32),
            numpy_state["pos"],
            numpy_state["has_gauss"],
            state["numpy_gauss"],
        )
    )
    random.setstate((3, tuple(state["python"]), state["python_gauss"]))


# --------------------------------------------------------------------------- atomic write


def _fsync_dir(directory: pathlib.Path) -> None:
    with contextlib.suppress(OSError):  # not every filesystem/OS lets a folder be opened
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _temp_prefix(path: pathlib.Path) -> str:
    return f".{path.name}."


def _temp_suffix(path: pathlib.Path) -> str:
    return f".tmp{path.suffix}"


def remove_stale_temp_files(path: str | os.PathLike) -> list[pathlib.Path]:
    """Delete temp files left next to ``path`` by writes that were killed; the checkpoint itself is untouched.

    :param path: a checkpoint path
    :return: the deleted files
    """
    path = pathlib.Path(path)
    removed = []
    if path.parent.is_dir():
        for stale in path.parent.glob(_temp_prefix(path) + "*" + _temp_suffix(path)):
            with contextlib.suppress(OSError):
                stale.unlink()
                removed.append(stale)
    return removed


def write_atomically(path: str | os.PathLike, write: Callable[[pathlib.Path], None]) -> pathlib.Path:
    """Call ``write(temp_path)``, flush the temp file to disk, then rename it over ``path``.

    The temp file is in the same folder (so the rename is atomic): a crash at any point leaves either the
    previous file or the new one at ``path``, never a partial file.

    :param path: destination
    :param write: writes the complete file at the path it is given
    :return: the path written
    """
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=_temp_prefix(path), suffix=_temp_suffix(path))
    os.close(fd)
    tmp = pathlib.Path(tmp_name)
    try:
        write(tmp)
        with open(tmp, "rb+") as file:
            os.fsync(file.fileno())
        os.replace(tmp, path)
        _fsync_dir(path.parent)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    return path


def save_checkpoint(model: OfflineAlgorithm, path: str | os.PathLike, check_finite: bool = True) -> pathlib.Path:
    """Write ``model`` and the global RNG states to ``path`` atomically (:func:`write_atomically`).

    :param model: the model
    :param path: destination (``.zip`` is appended if missing)
    :param check_finite: refuse (:class:`DivergenceError`) to write NaN or inf parameters
    :return: the path written
    """
    path = pathlib.Path(path)
    if path.suffix != ".zip":
        path = path.with_name(path.name + ".zip")
    if check_finite:
        model.check_finite(parameters_only=True, consequence=f"Not saving {path}")

    def write(tmp: pathlib.Path) -> None:
        model.save(tmp, check_finite=False)
        buffer = io.BytesIO()
        th.save({"format": _FORMAT_VERSION, "num_timesteps": model.num_timesteps, "rng": get_rng_state()}, buffer)
        with zipfile.ZipFile(tmp, mode="a") as archive:
            archive.writestr(RNG_MEMBER, buffer.getvalue())

    return write_atomically(path, write)


def read_rng_state(path: str | os.PathLike) -> dict[str, Any] | None:
    """The RNG states stored in a checkpoint, or ``None`` for a plain model file.

    :param path: checkpoint path
    """
    with zipfile.ZipFile(path) as archive:
        if RNG_MEMBER not in archive.namelist():
            return None
        payload = th.load(io.BytesIO(archive.read(RNG_MEMBER)), weights_only=True)
    return payload["rng"]


def load_checkpoint(
    algorithm_class: type[OfflineAlgorithm],
    path: str | os.PathLike,
    restore_rng: bool = True,
    **load_kwargs: Any,
) -> OfflineAlgorithm:
    """Load a checkpoint to continue training: ``algorithm_class.load`` then the saved RNG states.

    Continue with ``model.learn(total - model.num_timesteps, reset_num_timesteps=False)`` to end at
    the same ``total`` (and so the same learning-rate schedule) as the uninterrupted run.

    :param algorithm_class: e.g. ``POLA``
    :param path: checkpoint path
    :param restore_rng: set the global torch/NumPy/Python RNGs to their state at the save
    :param load_kwargs: passed to ``load`` (``dataset=``, ``env=``, ``device=``, ...)
    :return: the model
    """
    model = algorithm_class.load(pathlib.Path(path), **load_kwargs)
    if restore_rng:
        state = read_rng_state(path)
        if state is not None:
            set_rng_state(state)
    return model


# --------------------------------------------------------------------------- a part shared between runs


def save_module_state(module: th.nn.Module, path: str | os.PathLike) -> pathlib.Path:
    """Write ``module.state_dict()`` to ``path`` atomically (e.g. a fitted dynamics model that other runs reuse).

    :param module: the module
    :param path: destination (a ``torch.save`` file)
    :return: the path written
    """
    return write_atomically(path, lambda tmp: th.save(module.state_dict(), tmp))


def load_module_state(module: th.nn.Module, path: str | os.PathLike, device: th.device | str = "cpu") -> th.nn.Module:
    """Load a state dict written by :func:`save_module_state` into ``module``.

    :param module: the module, of the same architecture
    :param path: the file
    :param device: where the tensors are mapped to
    :return: ``module``
    """
    module.load_state_dict(th.load(path, map_location=device, weights_only=True))
    return module


# --------------------------------------------------------------------------- callback and entry point


class CheckpointCallback(BaseCallback):
    """Write ``<save_path>/<name_prefix>_latest.zip`` atomically every ``save_freq`` gradient steps.

    The checkpoint holds everything needed to resume exactly (see :func:`save_checkpoint`). It is
    also written at the first step of every ``learn`` call (so a fitted dynamics model is kept at
    once) and when training ends. Before each write the parameters and the accumulated losses are
    checked: NaN or inf raises :class:`DivergenceError` and the last good checkpoint stays in place.

    :param save_freq: gradient steps between two checkpoints
    :param save_path: folder of the checkpoints
    :param name_prefix: file name prefix
    :param keep_history: also keep a copy per save, ``<name_prefix>_<steps>_steps.zip``
    :param save_on_start: write a checkpoint at the first step of ``learn``
    :param verbose: 1 prints a line per checkpoint
    """

    def __init__(
        self,
        save_freq: int,
        save_path: str | os.PathLike,
        name_prefix: str = "pola",
        keep_history: bool = False,
        save_on_start: bool = True,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        if save_freq < 1:
            raise ValueError(f"save_freq must be >= 1, got {save_freq}")
        self.save_freq = save_freq
        self.save_path = pathlib.Path(save_path)
        self.name_prefix = name_prefix
        self.keep_history = keep_history
        self.save_on_start = save_on_start
        self.last_saved_step: int | None = None
        self.n_saves = 0
        self._first_step = True

    @property
    def latest_path(self) -> pathlib.Path:
        """Path of the latest checkpoint."""
        return latest_checkpoint_path(self.save_path, self.name_prefix)

    def _init_callback(self) -> None:
        self.save_path.mkdir(parents=True, exist_ok=True)
        remove_stale_temp_files(self.latest_path)

    def _on_training_start(self) -> None:
        self._first_step = True

    def save(self) -> pathlib.Path:
        """Write the checkpoint now (after the finite check) and return its path."""
        model: OfflineAlgorithm = self.model  # type: ignore[assignment]
        kept = f"Not saving; the last good checkpoint {self.latest_path} (step {self.last_saved_step}) is kept"
        model.check_finite(consequence=kept)
        path = save_checkpoint(model, self.latest_path, check_finite=False)
        if self.keep_history:
            save_checkpoint(model, self.save_path / f"{self.name_prefix}_{self.num_timesteps}_steps.zip", check_finite=False)
        self.last_saved_step = self.num_timesteps
        self.n_saves += 1
        if self.verbose >= 1:
            print(f"Saved checkpoint {path} at step {self.num_timesteps}")
        return path

    def _on_step(self) -> bool:
        if self.num_timesteps % self.save_freq == 0 or (self._first_step and self.save_on_start):
            self.save()
        self._first_step = False
        return True

    def _on_training_end(self) -> None:
        if self.last_saved_step != self.num_timesteps:
            self.save()


def latest_checkpoint_path(save_path: str | os.PathLike, name_prefix: str = "pola") -> pathlib.Path:
    """Where :class:`CheckpointCallback` keeps its latest checkpoint: ``<save_path>/<name_prefix>_latest.zip``."""
    return pathlib.Path(save_path) / f"{name_prefix}_latest.zip"


def load_or_make(
    algorithm_class: type[OfflineAlgorithm],
    path: str | os.PathLike,
    make_model: Callable[[], OfflineAlgorithm],
    **load_kwargs: Any,
) -> OfflineAlgorithm:
    """Resume from the checkpoint at ``path`` (:func:`load_checkpoint`) if there is one, else ``make_model()``.

    Temp files left next to ``path`` by a killed write are removed first.

    :param algorithm_class: class to load the checkpoint with (e.g. ``POLA``)
    :param path: checkpoint path
    :param make_model: builds a fresh (seeded) model when there is no checkpoint
    :param load_kwargs: arguments of ``load`` (``dataset=``, ``env=``, ``device=``, ...)
    :return: the model; ``model.num_timesteps`` is the step it continues from (0 for a fresh one)
    """
    remove_stale_temp_files(path)
    if pathlib.Path(path).is_file():
        return load_checkpoint(algorithm_class, path, **load_kwargs)
    return make_model()


def learn_with_checkpoints(
    algorithm_class: type[OfflineAlgorithm],
    make_model: Callable[[], OfflineAlgorithm],
    total_timesteps: int,
    save_path: str | os.PathLike,
    save_freq: int = 10_000,
    name_prefix: str = "pola",
    load_kwargs: dict[str, Any] | None = None,
    callback: MaybeCallback = None,
    **learn_kwargs: Any,
) -> OfflineAlgorithm:
    """Train to ``total_timesteps`` gradient steps, resuming from the latest checkpoint in ``save_path`` if there is one.

    Start, kill and re-run this as often as needed: every run continues where the last checkpoint
    left off, and the final parameters are those of one uninterrupted run.

    :param algorithm_class: class to load a checkpoint with (e.g. ``POLA``)
    :param make_model: builds a fresh (seeded) model when there is no checkpoint
    :param total_timesteps: gradient steps of the whole run (not of this call)
    :param save_path: checkpoint folder
    :param save_freq: gradient steps between checkpoints
    :param name_prefix: checkpoint file prefix
    :param load_kwargs: arguments of ``load`` on resume (``dataset=``, ``env=``, ``device=``, ...)
    :param callback: more callbacks, run after the checkpoint callback
    :param learn_kwargs: passed to ``learn`` (``log_interval``, ``progress_bar``, ...)
    :return: the trained model
    """
    latest = latest_checkpoint_path(save_path, name_prefix)
    resumed = latest.is_file()
    model = load_or_make(algorithm_class, latest, make_model, **(load_kwargs or {}))
    remaining, reset = (total_timesteps - model.num_timesteps, False) if resumed else (total_timesteps, True)
    checkpoint = CheckpointCallback(save_freq, save_path, name_prefix)
    checkpoint.last_saved_step = model.num_timesteps if not reset else None
    callbacks: list[BaseCallback] = [checkpoint]
    if callback is not None:
        from stable_baselines3.common.callbacks import CallbackList, ConvertCallback

        if isinstance(callback, list):
            callbacks.append(CallbackList(callback))
        elif isinstance(callback, BaseCallback):
            callbacks.append(callback)
        else:
            callbacks.append(ConvertCallback(callback))
    if remaining > 0:
        model.learn(remaining, callback=callbacks, reset_num_timesteps=reset, **learn_kwargs)
    return model


__all__ = [
    "RNG_MEMBER",
    "CheckpointCallback",
    "DivergenceError",
    "ModelFileError",
    "get_rng_state",
    "latest_checkpoint_path",
    "learn_with_checkpoints",
    "load_checkpoint",
    "load_module_state",
    "load_or_make",
    "read_rng_state",
    "remove_stale_temp_files",
    "save_checkpoint",
    "save_module_state",
    "set_rng_state",
    "validate_model_file",
    "write_atomically",
]
