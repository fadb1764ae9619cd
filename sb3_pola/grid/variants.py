"""The score grid's variants (POLA's ablations), presets and evaluation rules: what decides a cell's result.

A variant is a name for a set of POLA arguments (``T3``: ``rollout_length=3``; ``BC``: ``eta=0``); a
:class:`Config` holds the budget and hyperparameters every cell of a grid shares (its :meth:`Config.signature`
keeps two grids from sharing an output folder); an evaluation rule says how the evaluations act.
"""

from __future__ import annotations

import argparse
import hashlib
import inspect
import json
import re
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import torch as th

from sb3_pola.common.errors import UsageError
from sb3_pola.common.schedules import WarmupSchedule, cosine_schedule
from sb3_pola.pola import PAPER_FORM, POLA

# name -> (label for legends, POLA keyword arguments, policy_kwargs)
VARIANTS: dict[str, tuple[str, dict[str, Any], dict[str, Any]]] = {
    "T0": ("POLA T=0 (no look-ahead)", {"rollout_length": 0}, {}),
    "T1": ("POLA T=1", {"rollout_length": 1}, {}),
    "T3": ("POLA T=3", {"rollout_length": 3}, {}),
    "T5": ("POLA T=5", {"rollout_length": 5}, {}),
    # the actor on the state's products (paper section V, with the critics' Mish); the default since #23 is the raw state
    "T0-products": ("T=0, products in the actor", {"rollout_length": 0, "use_state_products": True}, {}),
    "T3-products": ("T=3, products in the actor", {"rollout_length": 3, "use_state_products": True}, {}),
    "T3-criticproducts": (
        "T=3, products in actor and critic",
        {"rollout_length": 3, "use_state_products": True},
        {"critic_state_products": True},
    ),
    # the raw state named explicitly: T0 and T3 themselves since #23 (kept for the folders made before it)
    "T0-noproducts": ("T=0, no products", {"rollout_length": 0, "use_state_products": False}, {}),
    "T3-noproducts": ("T=3, no products", {"rollout_length": 3, "use_state_products": False}, {}),
    "BC": ("BC (diffusion actor, eta=0)", {"rollout_length": 0, "eta": 0.0}, {}),
}
ALL_VARIANTS = list(VARIANTS)
# the variants of each figure (paper Fig. 3 and Fig. 4); BC is drawn in both as the floor
FIGURES: dict[str, list[str]] = {
    "rollout": ["T0", "T1", "T3", "T5", "BC"],
    "products": ["T3", "T3-products", "T3-criticproducts", "T0", "T0-products", "BC"],
}
# POLA's numbers in the paper's Table I (D4RL MuJoCo v2, mean +- std over 10 replications)
PAPER_TABLE_I: dict[tuple[str, str], str] = {
    ("halfcheetah", "medium-expert"): "111.2 ± 2.4",
    ("halfcheetah", "medium-replay"): "62.1 ± 1.3",
    ("halfcheetah", "medium"): "71.8 ± 0.4",
    ("halfcheetah", "random"): "33.7 ± 1.9",
    ("hopper", "medium-expert"): "111.3 ± 1.7",
    ("hopper", "medium-replay"): "102.1 ± 1.8",
    ("hopper", "medium"): "92.3 ± 4.2",
    ("hopper", "random"): "31.6 ± 0.8",
    ("walker2d", "medium-expert"): "118.7 ± 0.2",
    ("walker2d", "medium-replay"): "89.2 ± 1.3",
    ("walker2d", "medium"): "104.3 ± 0.6",
    ("walker2d", "random"): "21.6 ± 1.4",
}


def paper_task(dataset_id: str) -> tuple[str, str] | None:
    """The paper's (env, quality) of a dataset id: ``halfcheetah/medium-v0`` -> ``("halfcheetah", "medium")``.

    :param dataset_id: Minari id (``halfcheetah/medium-v0``, ``mujoco/hopper/medium-v0``) or D4RL name
    :return: the task key of :data:`PAPER_TABLE_I`, or ``None``
    """
    name = dataset_id.lower()
    env = next((e for e in ("halfcheetah", "hopper", "walker2d") if e in name), None)
    if env is None:
        return None
    rest = name.split(env, 1)[1]
    for quality in ("medium-expert", "medium-replay", "medium", "random"):  # longest names first
        if re.search(rf"(^|[/_-]){quality}($|[/_-])", rest):
            return env, quality
    return None


@dataclass
class Config:
    """Everything that decides a cell's result (a change of any field is another experiment).

    :param preset: name of the preset this came from
    :param steps: gradient steps per cell
    :param eval_freq: gradient steps between evaluations
    :param eval_episodes: episodes per evaluation
    :param batch_size: minibatch size
    :param net_arch: hidden sizes of actor and critics, a list for both or ``dict(pi=[...], qf=[...])``
    :param n_critics: critic ensemble size ``N``
    :param top_k: ``K`` smallest Q-values averaged in the policy loss
    :param n_action_samples: candidate actions per state at evaluation (picked by the critic)
    :param eval_rule: how the evaluations during training pick actions (:func:`apply_eval_rule`): ``ema``
        (the default: the deterministic ``predict`` of the variant's predict actor, one chain under its
        ``deterministic_rule`` or ``n_action_samples`` candidates), ``stochastic``
        (one sample of the EMA actor's noisy chain), ...; a rule other than ``ema`` overrides ``n_action_samples``
    :param dynamics_kwargs: arguments of the dynamics ensemble
    :param dynamics_fit_kwargs: arguments of its fit
    :param share_dynamics: fit the dynamics model once per dataset (first seed) and share it across seeds
    :param extra: further POLA keyword arguments
    :param log_interval: gradient steps between rows of the training statistics (``train/<cell>/``)
    """

    preset: str
    steps: int
    eval_freq: int
    eval_episodes: int
    batch_size: int = 256
    net_arch: list[int] | dict[str, list[int]] = field(default_factory=lambda: [256, 256, 256])
    n_critics: int = 10
    top_k: int = 2
    n_action_samples: int = 1
    dynamics_kwargs: dict[str, Any] = field(default_factory=dict)
    dynamics_fit_kwargs: dict[str, Any] = field(default_factory=dict)
    share_dynamics: bool = False
    extra: dict[str, Any] = field(default_factory=dict)
    log_interval: int = 500
    eval_rule: str = "ema"

    def signature(self) -> str:
        """Short hash of the fields that decide results (the preset's name and the logging period excluded)."""
        data = {k: v for k, v in asdict(self).items() if k not in ("preset", "log_interval")}
        if data["eval_rule"] == "ema":  # the rule before it was a field: folders made then keep their signature
            del data["eval_rule"]
        # POLA's defaults where they depart from the paper's form (issue #12): a folder made under the old
        # defaults (the paper's form) keeps its signature, and cannot be resumed with the new ones by mistake
        changed = {key: value for key, value in pola_defaults(PAPER_FORM).items() if value != PAPER_FORM[key]}
        if changed:
            data["pola_defaults"] = changed
        # repr: a schedule (a learning rate given as one) is not JSON; its repr names its parameters
        return hashlib.sha1(json.dumps(data, sort_keys=True, default=repr).encode()).hexdigest()[:10]


# POLA arguments a cell passes from the configuration or the command line, with the flag that sets each
GRID_ARGUMENTS: dict[str, str] = {
    "batch_size": "--batch-size",
    "n_critics": "--n-critics",
    "top_k": "--top-k",
    "dynamics_kwargs": "--dynamics-kwargs",
    "dynamics_fit_kwargs": "--dynamics-steps",
    "seed": "--seeds",
    "device": "--device",
    "dataset": "--datasets",
}


def pola_defaults(keys: Any) -> dict[str, Any]:
    """The defaults of these ``POLA`` arguments."""
    parameters = inspect.signature(POLA.__init__).parameters
    return {key: parameters[key].default for key in keys}


PRESETS: dict[str, Config] = {
    # a CPU core per cell: light critics, small ensemble, the main job's dynamics model, a short budget, the
    # compiled update (faster per step for the look-ahead variants; the first step compiles for minutes); the actor
    # 2 x 256 as d3rlpy's BC (on the raw state it costs less than 2 x 128 on the products of a 17-dim state)
    "cpu": Config(
        preset="cpu",
        steps=10_000,
        eval_freq=2000,
        eval_episodes=10,
        batch_size=128,
        net_arch={"pi": [256, 256], "qf": [128, 128]},
        n_critics=5,
        top_k=2,
        n_action_samples=1,
        dynamics_kwargs={"n_members": 5, "n_elites": 3, "hidden_dim": 128, "n_layers": 3},
        dynamics_fit_kwargs={"max_steps": 2000},
        share_dynamics=True,
        extra={"compile_update": True},
    ),
    # the paper's configuration (N = 10, 3 x 256, batch 256, the paper's form of the Q term), Diffusion-QL's
    # 50 candidate actions
    "paper": Config(
        preset="paper",
        steps=1_000_000,
        eval_freq=10_000,
        eval_episodes=10,
        batch_size=256,
        net_arch=[256, 256, 256],
        n_critics=10,
        top_k=2,
        n_action_samples=50,
        extra=dict(PAPER_FORM),
    ),
}
DEFAULT_DATASETS = ["halfcheetah/medium-v0", "halfcheetah/medium-replay-v0"]
DEFAULT_VARIANTS = ["T0", "T1", "T3", "T5", "T3-products", "T3-criticproducts", "BC"]


def resolve_device(device: str) -> str:
    """``auto`` -> ``cuda`` when available, else ``cpu``."""
    if device != "auto":
        return device
    return "cuda" if th.cuda.is_available() else "cpu"


def build_config(args: argparse.Namespace, device: str) -> Config:
    """The preset (``auto``: ``paper`` on CUDA, else ``cpu``) with the command line's overrides."""
    preset = args.preset if args.preset != "auto" else ("paper" if device.startswith("cuda") else "cpu")
    config = replace(PRESETS[preset])
    overrides = {
        "steps": args.steps,
        "eval_freq": args.eval_freq,
        "eval_episodes": args.eval_episodes,
        "batch_size": args.batch_size,
        "net_arch": args.net_arch,
        "n_critics": args.n_critics,
        "top_k": args.top_k,
        "n_action_samples": args.n_action_samples,
        "log_interval": args.log_interval,
        "eval_rule": args.eval_rule,
    }
    config = replace(config, **{k: v for k, v in overrides.items() if v is not None})
    if args.dynamics_steps is not None:
        config.dynamics_fit_kwargs = {**config.dynamics_fit_kwargs, "max_steps": args.dynamics_steps}
    if args.dynamics_kwargs:
        config.dynamics_kwargs = {**config.dynamics_kwargs, **_json(args.dynamics_kwargs)}
    if args.share_dynamics is not None:
        config.share_dynamics = args.share_dynamics
    if args.extra:
        config.extra = {**config.extra, **_json(args.extra)}
    passed_by_cell = [key for key in GRID_ARGUMENTS if key in config.extra]
    if passed_by_cell:  # POLA would get them twice and fail only when its first cell starts
        flags = ", ".join(f"{key} (use {GRID_ARGUMENTS[key]})" for key in passed_by_cell)
        raise UsageError(f"--extra cannot set the arguments every cell passes itself: {flags}")
    if args.compile is not None:
        config.extra = {**config.extra, "compile_update": args.compile}
    config.top_k = min(config.top_k, config.n_critics)
    parse_eval_rule(config.eval_rule)
    if config.steps < 1 or config.eval_freq < 1 or config.eval_episodes < 1:
        raise UsageError("steps, eval_freq and eval_episodes must be positive")
    return config


def _json(value: str | dict[str, Any]) -> dict[str, Any]:
    """A JSON object given on the command line (already parsed by the parser's type, or text)."""
    return json.loads(value) if isinstance(value, str) else dict(value)


def pola_kwargs(extra: dict[str, Any]) -> dict[str, Any]:
    """POLA keyword arguments from JSON-able ones: ``"eta_warmup": [warmup, ramp]`` becomes a
    :class:`~sb3_pola.common.schedules.WarmupSchedule` of ``eta`` (behaviour cloning, then a linear ramp);
    ``"lr_cos": X`` a cosine decay of ``learning_rate`` from X to 0 (the default before #23's thirteenth pass),
    ``"lr_cos": [X, final, start]`` one from X to ``final`` that begins after the ``start`` fraction of training;
    ``"bc_lr_cos"`` the same for ``bc_learning_rate``."""
    kwargs = dict(extra)
    for key, name in (("lr_cos", "learning_rate"), ("bc_lr_cos", "bc_learning_rate")):
        if key in kwargs:
            value = kwargs.pop(key)
            kwargs[name] = cosine_schedule(*map(float, value if isinstance(value, list) else [value]))
    if "eta_warmup" in kwargs:
        warmup, ramp = kwargs.pop("eta_warmup")
        eta = float(kwargs.get("eta", pola_defaults(["eta"])["eta"]))
        if eta != 0:  # behaviour cloning stays behaviour cloning
            kwargs["eta"] = WarmupSchedule(eta, warmup, ramp)
    return kwargs


def needs_dynamics(variant: str, config: Config) -> bool:
    """Whether a variant's model has a dynamics model to fit (a look-ahead, ``rollout_length > 0``)."""
    default = pola_defaults(["rollout_length"])["rollout_length"]
    return int(pola_kwargs({**config.extra, **VARIANTS[variant][1]}).get("rollout_length", default)) > 0


def apply_eval_rule(model: Any, rule: str) -> bool:
    """Set how ``model.predict`` picks actions; return the ``deterministic`` flag to call it with.

    :param model: a POLA model
    :param rule: ``ema`` (the EMA actor's deterministic ``predict``, the default: the chain under the policy's
        ``deterministic_rule``, the mode of the chain's samples unless set otherwise), ``online`` (the same of the trained
        actor), ``stochastic`` / ``online-stochastic`` (one sample of the noisy reverse chain, the
        policy Diffusion-QL trains) or ``candidates<N>`` / ``online-candidates<N>`` (N noisy candidates of the
        EMA / online actor, the one with the highest pessimistic Q kept, as Diffusion-QL evaluates)
    """
    model.policy.predict_actor, model.policy.n_action_samples, deterministic = parse_eval_rule(rule)
    return deterministic


def parse_eval_rule(rule: str) -> tuple[str, int, bool]:
    """``(predict_actor, n_action_samples, deterministic)`` of an evaluation rule (see :func:`apply_eval_rule`)."""
    match = re.fullmatch(r"(online-)?(stochastic|candidates(\d+))", rule)
    if rule in ("ema", "online"):
        return rule, 1, True
    if match is None or (match.group(3) is not None and int(match.group(3)) < 1):
        raise UsageError(f"unknown evaluation rule {rule!r}: ema, online, [online-]stochastic or [online-]candidates<N>")
    actor = "online" if match.group(1) else "ema"
    if match.group(2) == "stochastic":
        return actor, 1, False
    return actor, int(match.group(3)), True
