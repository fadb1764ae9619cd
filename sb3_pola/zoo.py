"""rl-zoo3 launchers for POLA: ``sb3-pola train|enjoy|optimize`` (or ``python -m sb3_pola.zoo ...``).

The zoo knows its algorithms through the dict ``rl_zoo3.utils.ALGOS`` and freezes ``--algo``'s
choices when its parser is built, so ``python -m rl_zoo3.train --algo pola`` cannot work. These
launchers register POLA (``ALGOS``, the optimizer's ``HYPERPARAMS_SAMPLER`` and
``HYPERPARAMS_CONVERTER``), register one Gymnasium env per offline dataset, and then run the zoo's
own ``train()`` / ``enjoy()`` on the remaining arguments, so every zoo flag works as usual
(``-conf``, ``-params``, ``--eval-freq``, ``--save-freq``, ``-tb``, ``-i``, ``--seed``, ``-f``,
``-P``, ``--storage``, ``--study-name``...). Defaults added when absent: ``--algo pola`` and, for
``train``/``optimize``, ``-conf`` the package's ``sb3_pola/hyperparams/pola.yml`` (installed with it, see
:func:`default_config`); ``optimize`` adds ``-optimize``. rl-zoo3, PyYAML and Optuna come with the ``zoo`` extra.

Naming: ``--env <dataset>`` selects both the env and the dataset. A dataset's env id is its Minari
id with every ``/`` but the last turned into ``-`` (Gymnasium ids allow one namespace):

- ``halfcheetah/medium-v0`` (local or made by ``sb3-pola collect``) -> ``--env halfcheetah/medium-v0``
- ``mujoco/hopper/medium-v0`` (Minari's official id) -> ``--env mujoco-hopper/medium-v0``

The env is the dataset's own (rebuilt from its Minari ``env_spec``, time limit included), or, for a
known dataset that is not on disk, the Gymnasium env of its family (``Hopper-v5``). The YAML entry
keyed by the env id may set ``dataset:``; when it does not, the launcher passes the dataset of the
env id. Logs go to ``<log folder>/pola/<env id with / as ->_<run>``, as the zoo names them.

Offline specifics: ``n_timesteps`` counts gradient steps (so do ``--eval-freq`` and ``--save-freq``);
the zoo's training env is made but never stepped; evaluations log ``eval/normalized_score``
(and ``evaluations.npz`` gets ``normalized_scores``); ``-i`` continues the step count of the loaded
model; ``--save-replay-buffer`` is ignored (the replay buffer is the dataset).
"""

from __future__ import annotations

import contextlib
import importlib.resources
import os
import pathlib
import socket
import sys
from collections.abc import Iterable, Iterator
from typing import Any

import gymnasium as gym
from gymnasium.envs.registration import parse_env_id

from sb3_pola.common.callbacks import NormalizedScoreEvalCallback
from sb3_pola.common.dataset_paths import DatasetError, DatasetNotFoundError, list_local_datasets, resolve_dataset_path
from sb3_pola.common.datasets import D4RL_KINDS, make_env
from sb3_pola.common.offline_algorithm import OfflineAlgorithm
from sb3_pola.pola.pola import POLA

ALGO_NAME = "pola"
COMMANDS = ("train", "enjoy", "optimize")

# Dataset family (first part of a dataset id) -> Gymnasium env, used when the dataset is not on disk.
FAMILY_ENVS: dict[str, str] = {
    "halfcheetah": "HalfCheetah-v5",
    "hopper": "Hopper-v5",
    "walker2d": "Walker2d-v5",
    "ant": "Ant-v5",
    "invertedpendulum": "InvertedPendulum-v5",
    "inverteddoublependulum": "InvertedDoublePendulum-v5",
}
# Minari's official MuJoCo datasets (mujoco/<family>/<level>-v0) and the D4RL kinds `sb3-pola collect` makes.
MINARI_LEVELS = ("expert", "medium", "simple")

# env id -> dataset id, for every env registered here
DATASET_ENVS: dict[str, str] = {}


# ----------------------------------------------------------------------------- naming and envs


def env_id_for_dataset(dataset_id: str) -> str:
    """The Gymnasium id that names a dataset on the zoo's command line.

    ``a/b-v0`` stays as it is; ``mujoco/hopper/medium-v0`` becomes ``mujoco-hopper/medium-v0``.

    :param dataset_id: Minari dataset id
    :return: a valid Gymnasium env id
    """
    head, sep, last = dataset_id.rpartition("/")
    env_id = f"{head.replace('/', '-')}{sep}{last}"
    parse_env_id(env_id)  # raises gymnasium's error for ids it cannot name
    return env_id


def dataset_for_env(env_id: str) -> str | None:
    """The dataset registered under ``env_id`` (``None`` for an ordinary env)."""
    return DATASET_ENVS.get(env_id)


def _family_env(dataset_id: str) -> str | None:
    parts = dataset_id.split("/")
    family = parts[1] if parts[0] == "mujoco" and len(parts) > 2 else parts[0]
    return FAMILY_ENVS.get(family.lower())


def make_dataset_env(dataset_id: str, fallback_env_id: str | None = None, **kwargs: Any) -> gym.Env:
    """Entry point of a dataset's env: the env the dataset was recorded in.

    :param dataset_id: Minari dataset id (looked up as ``load_offline_dataset`` does)
    :param fallback_env_id: Gymnasium id used when the dataset is not on disk or records no env
    :param kwargs: arguments of ``gym.make`` (e.g. ``render_mode``)
    """
    try:
        resolve_dataset_path(dataset_id)
        return make_env(dataset_id, monitor=False, **kwargs)  # the zoo wraps its envs in a Monitor itself
    except DatasetError as error:
        if fallback_env_id is None:
            raise DatasetError(f"Cannot make the env of dataset {dataset_id!r}: {error}") from error
        return gym.make(fallback_env_id, **kwargs)


def register_dataset_env(dataset_id: str, env_id: str | None = None) -> str:
    """Register (once) a Gymnasium env named after ``dataset_id`` whose entry point builds the dataset's env.

    :param dataset_id: Minari dataset id
    :param env_id: id to register (default :func:`env_id_for_dataset`)
    :return: the env id
    """
    env_id = env_id or env_id_for_dataset(dataset_id)
    if env_id in DATASET_ENVS or env_id in gym.registry:
        if env_id in DATASET_ENVS and DATASET_ENVS[env_id] != dataset_id:
            raise ValueError(f"Env id {env_id!r} already names dataset {DATASET_ENVS[env_id]!r}, not {dataset_id!r}")
        return env_id
    gym.register(
        id=env_id,
        entry_point="sb3_pola.zoo:make_dataset_env",  # a string, so subprocess vec envs can rebuild it
        kwargs={"dataset_id": dataset_id, "fallback_env_id": _family_env(dataset_id)},
        disable_env_checker=True,  # the inner env is checked by its own gym.make
    )
    DATASET_ENVS[env_id] = dataset_id
    return env_id


def known_dataset_ids() -> list[str]:
    """Official Minari MuJoCo ids and ``sb3-pola collect`` ids (v0: small local scale, v1: the paper's scale)."""
    ids = [f"mujoco/{env}/{level}-v0" for env in ("halfcheetah", "hopper", "walker2d") for level in MINARI_LEVELS]
    ids += [f"{env}/{kind}-v{v}" for env in ("halfcheetah", "hopper", "walker2d") for kind in D4RL_KINDS for v in (0, 1)]
    return ids


def config_datasets(config: str | os.PathLike | None) -> dict[str, str]:
    """``{env id: dataset id}`` of the YAML entries that set ``dataset:`` (the key being the env id)."""
    if config is None or not str(config).endswith((".yml", ".yaml")) or not os.path.isfile(config):
        return {}
    import yaml

    with open(config) as file:
        entries = yaml.safe_load(file) or {}
    return {
        key: entry["dataset"]
        for key, entry in entries.items()
        if isinstance(entry, dict) and isinstance(entry.get("dataset"), str) and key != "default"
    }


def register_dataset_envs(config: str | os.PathLike | None = None, extra: Iterable[str] = ()) -> dict[str, str]:
    """Register the envs of the local datasets, of the known ids, of ``config``'s entries and of ``extra``.

    Local datasets come first, so a local dataset whose id maps to a known id's env id wins.

    :return: ``{env id: dataset id}`` of every dataset env registered so far
    """
    for dataset_id in [*list_local_datasets(), *extra, *known_dataset_ids()]:
        with contextlib.suppress(gym.error.Error, ValueError):
            register_dataset_env(dataset_id)
    for env_id, dataset_id in config_datasets(config).items():
        if env_id not in gym.registry:
            with contextlib.suppress(gym.error.Error, ValueError):
                register_dataset_env(dataset_id, env_id=env_id)
    return dict(DATASET_ENVS)


# ----------------------------------------------------------------------------- config


def default_config() -> pathlib.Path:
    """The zoo config installed with the package (``sb3_pola/hyperparams/pola.yml``), in a clone or an install.

    :return: path of the YAML file
    """
    resource = importlib.resources.files("sb3_pola").joinpath("hyperparams", f"{ALGO_NAME}.yml")
    return pathlib.Path(str(resource))


# ----------------------------------------------------------------------------- optimizer sampler


def convert_pola_params(sampled_params: dict[str, Any]) -> dict[str, Any]:
    """Trial parameters -> POLA arguments (``top_k`` is capped at ``n_critics``); also used by ``--trial-id``."""
    params = dict(sampled_params)
    if "top_k" in params and "n_critics" in params:
        params["top_k"] = min(int(params["top_k"]), int(params["n_critics"]))
    return params


def sample_pola_params(trial: Any, n_actions: int, n_envs: int, additional_args: dict[str, Any]) -> dict[str, Any]:
    """Optuna search space of POLA, in the zoo's sampler signature.

    Rollout length over the paper's ablation {0, 1, 3, 5}; ``eta`` log-uniform around the paper's 1;
    the critic ensemble and its top-K; the learning rate (actor and critic share it); the number of
    denoising steps. Each trial records which worker ran it (``worker`` user attribute).
    """
    trial.set_user_attr("worker", f"{socket.gethostname()}:{os.getpid()}")
    sampled = {
        "rollout_length": trial.suggest_categorical("rollout_length", [0, 1, 3, 5]),
        "eta": trial.suggest_float("eta", 0.1, 10.0, log=True),
        "n_critics": trial.suggest_categorical("n_critics", [2, 5, 10]),
        "top_k": trial.suggest_categorical("top_k", [1, 2, 3, 5]),
        "learning_rate": trial.suggest_float("learning_rate", 1e-5, 1e-3, log=True),
        "n_diffusion_steps": trial.suggest_categorical("n_diffusion_steps", [3, 5, 10, 20]),
    }
    return convert_pola_params(sampled)


# ----------------------------------------------------------------------------- experiment manager


def _offline(algo: str) -> bool:
    from rl_zoo3.utils import ALGOS

    cls = ALGOS.get(algo)
    return isinstance(cls, type) and issubclass(cls, OfflineAlgorithm)


@contextlib.contextmanager
def _patched(module: Any, name: str, value: Any) -> Iterator[None]:
    old = getattr(module, name)
    setattr(module, name, value)
    try:
        yield
    finally:
        setattr(module, name, old)


def _manager_class() -> type:
    """The zoo's ExperimentManager adapted to offline algorithms (built lazily: rl_zoo3 is an optional extra)."""
    import optuna
    import rl_zoo3.exp_manager as exp_manager
    from rl_zoo3.callbacks import TrialEvalCallback

    class NormalizedScoreTrialEvalCallback(NormalizedScoreEvalCallback, TrialEvalCallback):
        """The optimizer's pruning callback, logging the normalised score as a trial attribute too."""

        trial: optuna.Trial

        def _on_step(self) -> bool:
            continue_training = super()._on_step()
            if self.last_normalized_score is not None:
                self.trial.set_user_attr("normalized_score", self.last_normalized_score)
            return continue_training

    class OfflineExperimentManager(exp_manager.ExperimentManager):
        """ExperimentManager that gives POLA its dataset, normalised-score evaluation and continued step counts."""

        def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
            hyperparams, saved = super().read_hyperparameters()
            if _offline(self.algo) and "dataset" not in hyperparams:
                dataset = dataset_for_env(self.env_name.gym_id)
                if dataset is None:
                    raise ValueError(
                        f"No dataset for env {self.env_name.gym_id!r}: use a dataset's env id (e.g. "
                        f"halfcheetah/medium-v0, see `sb3-pola datasets`) or set `dataset:` in {self.config}"
                    )
                hyperparams["dataset"] = dataset
                saved = type(saved)(sorted({**saved, "dataset": dataset}.items()))
            return hyperparams, saved

        def create_callbacks(self) -> None:
            with _patched(exp_manager, "EvalCallback", NormalizedScoreEvalCallback):
                super().create_callbacks()

        def objective(self, trial: optuna.Trial) -> float:
            with _patched(exp_manager, "TrialEvalCallback", NormalizedScoreTrialEvalCallback):
                return super().objective(trial)

        def learn(self, model: Any) -> None:
            if self.continue_training and _offline(self.algo):
                # -i continues the loaded model's gradient-step count (checkpoints, logs, schedules)
                learn = model.learn
                model.learn = lambda *args, **kwargs: learn(*args, reset_num_timesteps=False, **kwargs)
                try:
                    super().learn(model)
                finally:
                    del model.learn
            else:
                super().learn(model)

        def hyperparameters_optimization(self) -> None:
            try:
                super().hyperparameters_optimization()
            except ImportError as error:
                # the zoo's CSV report needs pandas (rl_zoo3[plots]); the trials are already in the study
                if "pandas" not in str(error):
                    raise
                print(f"Optimization done; no CSV report written ({error}). Install rl_zoo3[plots] for it.")

        def save_trained_model(self, model: Any) -> None:
            if self.save_replay_buffer and _offline(self.algo):
                print("--save-replay-buffer ignored: an offline algorithm's replay buffer is its dataset")
                self.save_replay_buffer = False
            super().save_trained_model(model)

    return OfflineExperimentManager


# ----------------------------------------------------------------------------- launchers


def register_pola() -> None:
    """Make POLA known to rl-zoo3: ``ALGOS``, the optimizer's sampler and its trial-parameter converter."""
    from rl_zoo3.hyperparams_opt import HYPERPARAMS_CONVERTER, HYPERPARAMS_SAMPLER
    from rl_zoo3.utils import ALGOS

    ALGOS[ALGO_NAME] = POLA
    HYPERPARAMS_SAMPLER[ALGO_NAME] = sample_pola_params
    HYPERPARAMS_CONVERTER[ALGO_NAME] = convert_pola_params


def _option(args: list[str], *names: str) -> str | None:
    """Value of a command-line option given as ``--name value`` or ``--name=value``."""
    for i, arg in enumerate(args):
        for name in names:
            if arg == name and i + 1 < len(args):
                return args[i + 1]
            if arg.startswith(name + "="):
                return arg.split("=", 1)[1]
    return None


def zoo_arguments(command: str, args: list[str]) -> list[str]:
    """The zoo's arguments for a sub-command: ``--algo pola``, the default ``-conf``, ``-optimize``."""
    args = list(args)
    if _option(args, "--algo") is None:
        args = ["--algo", ALGO_NAME, *args]
    if command in ("train", "optimize") and _option(args, "-conf", "--conf-file") is None and default_config().is_file():
        args += ["-conf", str(default_config())]
    if command == "optimize" and not {"-optimize", "--optimize-hyperparameters"} & set(args):
        args.append("-optimize")
    return args


def check_env_option(dataset_envs: dict[str, str], env_id: str | None) -> None:
    """``--env`` names a dataset registered here or a Gymnasium env; else a one-line error, not rl-zoo3's guess.

    :param dataset_envs: ``{env id: dataset id}`` of the registered dataset envs
    :param env_id: the ``--env`` given (``None``: the zoo's default)
    :raises ~sb3_pola.common.dataset_paths.DatasetNotFoundError: neither
    """
    if env_id is None or env_id in gym.registry:
        return
    local = sorted(env for env, dataset in dataset_envs.items() if dataset in set(list_local_datasets()))
    raise DatasetNotFoundError(
        f"--env {env_id!r} is neither a local dataset nor a Gymnasium env. Local datasets as --env: "
        f"{', '.join(local) if local else 'none'} (`sb3-pola datasets` lists them; a Minari id's '/' but the last "
        "become '-'). Get one with `minari download <id>` or `sb3-pola collect`."
    )


def usage() -> str:
    return (
        "usage: sb3-pola {train,enjoy,optimize} [rl-zoo3 arguments]\n\n"
        f"  train     rl_zoo3 train --algo pola (defaults: -conf {default_config()})\n"
        "  enjoy     rl_zoo3 enjoy --algo pola\n"
        "  optimize  rl_zoo3 train --algo pola -optimize (add --storage/--study-name to share a study)\n\n"
        "--env is a dataset: its Minari id with all '/' but the last replaced by '-'\n"
        "(halfcheetah/medium-v0, mujoco-hopper/medium-v0). `sb3-pola datasets` lists local datasets.\n"
        "`sb3-pola train -h` shows the zoo's own flags."
    )


def main(argv: list[str] | None = None) -> int:
    """Run a zoo sub-command with POLA registered.

    :param argv: ``[command, *zoo arguments]`` with ``command`` one of ``train``, ``enjoy``, ``optimize``
    :return: exit status
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0
    command, rest = argv[0], argv[1:]
    if command not in COMMANDS:
        print(f"sb3-pola zoo: unknown command {command!r}\n\n{usage()}", file=sys.stderr)
        return 2
    import rl_zoo3.enjoy
    import rl_zoo3.train

    register_pola()
    args = zoo_arguments(command, rest)
    check_env_option(register_dataset_envs(config=_option(args, "-conf", "--conf-file")), _option(args, "--env"))
    entry = rl_zoo3.enjoy.enjoy if command == "enjoy" else rl_zoo3.train.train
    with _patched(sys, "argv", [f"sb3-pola {command}", *args]), _patched(rl_zoo3.train, "ExperimentManager", _manager_class()):
        try:
            entry()
        except SystemExit as error:  # argparse's -h and usage errors
            return error.code if isinstance(error.code, int) else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
