"""The fitted dynamics models kept between runs: a second ``learn`` on the same data and configuration skips the fit.

An entry is the fitted model's state dict, written and read as the score grid shares one fit per dataset
(:func:`~sb3_pola.common.checkpoint.save_module_state`, :func:`~sb3_pola.common.checkpoint.load_module_state`), in
``<cache>/dynamics/`` (``$SB3_POLA_CACHE_DIR``, else the user's cache folder; see
:func:`~sb3_pola.common.datasets.default_cache_dir`), with a JSON sidecar: the fit's metrics, the dataset, and torch's
random state after the fit.

The key is everything the fitted model depends on: the dataset's content (its fingerprint), the model's configuration
and initial weights, the fit's arguments, torch's random state when the fit starts (the seed and what the model's
construction drew before it), the device type and torch's version. A hit is therefore the model a fit would give, bit
for bit; it also restores the random state the fit would have left, so that training after a hit is the training after
a fit, bit for bit (on CPU). A model without a seed (``seed=None``: torch starts every process from another random
state) has no result to reproduce: its key leaves the initial weights and the random state out, so that any fit of the
same data, configuration and fit arguments is reused, and the random state is left as it is.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import pathlib
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch as th

from sb3_pola.common.checkpoint import load_module_state, save_module_state, write_atomically
from sb3_pola.common.dataset_cache import folder_size
from sb3_pola.common.datasets import default_cache_dir
from sb3_pola.common.dynamics import EnsembleDynamics

# Bump when a fit of the same inputs gives another model (the trainer's algorithm changed): old entries never hit.
DYNAMICS_CACHE_VERSION = 1


def dynamics_cache_dir() -> pathlib.Path:
    """``<cache>/dynamics``: the folder of the kept fits."""
    return default_cache_dir() / "dynamics"


def _digest_tensors(tensors: list[tuple[str, th.Tensor]]) -> str:
    digest = hashlib.sha256()
    for name, tensor in tensors:
        digest.update(name.encode())
        digest.update(tensor.detach().cpu().contiguous().view(-1).view(th.uint8).numpy().tobytes())
    return digest.hexdigest()


def data_fingerprint(dataset_fingerprint: str | None, arrays: Sequence[th.Tensor | np.ndarray]) -> str:
    """The data's part of the key: the dataset's content fingerprint, or (a dataset made in memory) a hash of the
    arrays the fit reads.

    :param dataset_fingerprint: :attr:`~sb3_pola.common.datasets.OfflineDataset.fingerprint`, if known
    :param arrays: the fit's arrays
    :return: a hex digest
    """
    if dataset_fingerprint:
        return dataset_fingerprint
    return _digest_tensors([(str(i), th.as_tensor(a)) for i, a in enumerate(arrays)])


def _rng_states(device: th.device) -> dict[str, th.Tensor]:
    states = {"cpu": th.get_rng_state()}
    if device.type == "cuda":
        states["cuda"] = th.cuda.get_rng_state(device)
    return states


def cache_key(
    model: EnsembleDynamics, data_key: str, fit_kwargs: dict[str, Any], device: th.device, exact: bool = True
) -> str:
    """The key of a fit: see the module's docstring. Read before the fit (initial weights, random state).

    :param model: the model about to be fitted
    :param data_key: :func:`data_fingerprint`
    :param fit_kwargs: the fit's arguments (those that change its result)
    :param device: where it is fitted
    :param exact: include the initial weights and the random state (a seeded model); ``False``: any fit of the data
        and configuration
    :return: a hex digest
    """
    config = {
        "version": DYNAMICS_CACHE_VERSION,
        "torch": th.__version__,
        "device": device.type,
        "data": data_key,
        "model": {
            name: getattr(model, name)
            for name in ("obs_dim", "action_dim", "n_members", "n_elites", "learn_termination", "mean_loss", "beta")
        }
        | {"weight_decays": list(model.weight_decays)},
        "fit": {key: fit_kwargs[key] for key in sorted(fit_kwargs)},
        "weights": _digest_tensors(sorted(model.state_dict().items())) if exact else "any",
        "rng": _digest_tensors(sorted(_rng_states(device).items())) if exact else "any",
    }
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()


def _encode(tensor: th.Tensor) -> str:
    return base64.b64encode(tensor.cpu().numpy().tobytes()).decode()


def _decode(text: str) -> th.Tensor:
    return th.frombuffer(bytearray(base64.b64decode(text)), dtype=th.uint8)


def fit_or_load(
    model: EnsembleDynamics,
    fit: Callable[[], dict[str, float]],
    key: str,
    about: dict[str, Any],
    use_cache: bool = True,
    verbose: int = 0,
    restore_rng: bool = True,
) -> dict[str, float]:
    """Load the fit of ``key`` from the cache, or run ``fit`` and keep its result there.

    :param model: the model to fit (on a hit, its weights are the cached ones)
    :param fit: fits ``model`` and returns its metrics
    :param key: :func:`cache_key`
    :param about: what the sidecar records besides (``dataset_id``, ``source``)
    :param use_cache: ``False``: fit, and keep nothing
    :param verbose: 1: a line saying the fit was loaded
    :param restore_rng: on a hit, set torch's random state to the one the fit left (an exact key)
    :return: the fit's metrics (``cached`` = 1 on a hit, ``fit_time`` then the time the load took)
    """
    if not use_cache:
        return fit()
    folder = dynamics_cache_dir()
    name = "".join(c if c.isalnum() or c in "-_." else "_" for c in str(about.get("dataset_id") or "dataset"))
    weights = os.path.join(folder, f"{name}-{key[:24]}.pt")
    sidecar = os.path.splitext(weights)[0] + ".json"
    device = model.obs_mean.device
    start = time.perf_counter()
    if os.path.isfile(weights) and os.path.isfile(sidecar):
        try:
            meta = json.loads(pathlib.Path(sidecar).read_text())
            if meta.get("key") == key:
                load_module_state(model, weights, device)
                if restore_rng:
                    th.set_rng_state(_decode(meta["rng"]["cpu"]))
                    if "cuda" in meta["rng"] and device.type == "cuda":
                        th.cuda.set_rng_state(_decode(meta["rng"]["cuda"]), device)
                os.utime(sidecar)  # last use, for `sb3-pola datasets --cache`
                info = {k: float(v) for k, v in meta["fit_info"].items()}
                info.update(cached=1.0, fit_time=time.perf_counter() - start)
                if verbose >= 1:
                    print(f"dynamics model loaded from the cache ({weights}): the fit of this data and configuration")
                return info
        except (OSError, ValueError, KeyError, RuntimeError) as error:  # a damaged entry: fitted again, rewritten
            print(f"dynamics cache entry {weights} unusable ({error}): fitting again")
    info = fit()
    try:
        save_module_state(model, weights)
        meta = {
            "key": key,
            "fit_info": info,
            "rng": {k: _encode(v) for k, v in _rng_states(device).items()},
            **about,
        }
        write_atomically(sidecar, lambda tmp: (tmp.write_text(json.dumps(meta)), None)[1])
    except OSError as error:
        print(f"could not keep the dynamics fit in {folder}: {error}")
    return info


def dynamics_entries() -> list[dict[str, Any]]:
    """The kept fits, as :func:`~sb3_pola.common.dataset_cache.cache_entries` lists the dataset arrays.

    :return: ``path``, ``kind`` (``"dynamics"``), ``dataset_id``, ``bytes``, ``last_used``, ``stale``
    """
    folder = os.fspath(dynamics_cache_dir())
    entries: list[dict[str, Any]] = []
    if not os.path.isdir(folder):
        return entries
    for file in sorted(os.listdir(folder)):
        if not file.endswith(".pt"):
            continue
        weights = os.path.join(folder, file)
        sidecar = os.path.splitext(weights)[0] + ".json"
        try:
            meta = json.loads(pathlib.Path(sidecar).read_text())
        except (OSError, ValueError):
            meta = {}
        source = meta.get("source")
        stale = "" if meta else "no sidecar"
        if source and not os.path.isdir(source):
            stale = "its dataset is gone"
        entries.append(
            {
                "path": pathlib.Path(weights),
                "kind": "dynamics",
                "dataset_id": meta.get("dataset_id") or file,
                "bytes": folder_size(pathlib.Path(weights)) + (os.path.getsize(sidecar) if meta else 0),
                "last_used": os.path.getmtime(sidecar if meta else weights),
                "stale": stale,
            }
        )
    return entries


__all__ = ["cache_key", "data_fingerprint", "dynamics_cache_dir", "dynamics_entries", "fit_or_load"]
