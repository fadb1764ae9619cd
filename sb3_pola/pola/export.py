"""Export the deterministic policy as one static graph (ONNX or TorchScript) that runs without sb3_pola.

The graph maps a batch of raw observations to the actions ``model.predict(obs, deterministic=True)``
returns: the state normalisation, the pairwise state products, the reverse chain of the predict actor (EMA or
online) unrolled over its fixed number of steps, ``mode_samples`` times with the observation's own noise
and their kernel mode (``deterministic_rule="mode"``, the default), once (``"observation_noise"``) or with no noise
(``"noise_free"``), the clip to ``[-1, 1]`` and the rescaling to the
action space's bounds. With ``n_action_samples > 1`` (the Q-ranked rule) the graph also holds the target critics:
it runs the chain for the ``n`` candidates of ``predict`` (their fixed noise held as a buffer) and keeps the one
with the highest minimum over the ensemble. With ``fallback_confidence`` (the confident choice) it holds the
imitation actor's chain too, and the critics that choose between the two actions. Input ``obs`` ``[batch,
obs_dim]`` (float32), output ``action`` ``[batch, action_dim]``, with a dynamic batch dimension.

``sb3-pola export MODEL.zip OUT [--format onnx|torchscript]``.
"""

from __future__ import annotations

import copy
import logging
import os
import pathlib
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from torch import nn

from sb3_pola.common.activations import FusedMish, TwiceDifferentiableMish, inference_mish
from sb3_pola.common.errors import UserError
from sb3_pola.common.torch_layers import StateProductsExtractor
from sb3_pola.pola.actor import DiffusionActor, kernel_mode, noise_from_projection, observation_noise_projection
from sb3_pola.pola.critic import EnsembleCritic
from sb3_pola.pola.fast_sampling import InferencePlan, inference_plan, run_plan
from sb3_pola.pola.policies import POLAPolicy, choose_confident

EXPORT_FORMATS = ("onnx", "torchscript")
INPUT_NAME = "obs"
OUTPUT_NAME = "action"
# suffixes that make ``sb3-pola export`` write TorchScript without ``--format``
TORCHSCRIPT_SUFFIXES = (".pt", ".pth", ".ts", ".jit")


class PolicyExportError(UserError, ValueError):
    """The policy cannot be exported (a configuration the static graph cannot reproduce)."""


class DeterministicPolicyGraph(nn.Module):
    """``model.predict(obs, deterministic=True)`` as a plain module of static shapes: ``[B, obs] -> [B, A]``.

    The reverse chain is ``predict``'s own fast form (:func:`~sb3_pola.pola.fast_sampling.inference_plan` and the
    loop that runs it): the predict actor's weights rearranged once (each step's time embedding through the first
    layer, the reverse step folded into the last layer), held here as buffers, and the chain unrolled over its fixed
    number of steps; only the activation differs (``nn.Mish`` for the eager in-place form). Built by
    :func:`export_policy`.

    :param policy: the policy to reproduce (finite action bounds)
    :param actor: the actor whose chain the graph runs (``None``: the predict actor, with the fallback actor's own
        graph and the choice between them where the policy has ``fallback_confidence``)
    """

    obs_mean: th.Tensor
    obs_std: th.Tensor
    idx_i: th.Tensor
    idx_j: th.Tensor
    w_state_t: th.Tensor
    b_in: th.Tensor
    w_action_t: th.Tensor
    time_proj: th.Tensor
    w_last_t: th.Tensor
    step_bias: th.Tensor
    action_low: th.Tensor
    action_high: th.Tensor
    noise_projection: th.Tensor
    noise_offset: th.Tensor
    candidate_noise: th.Tensor

    def __init__(self, policy: POLAPolicy, actor: DiffusionActor | None = None) -> None:
        super().__init__()
        check_exportable(policy)
        extractor = policy.features_extractor
        assert isinstance(extractor, StateProductsExtractor)
        # fallback_confidence: the imitation actor's chain as a graph of its own, and the critics that choose
        self.fallback: DeterministicPolicyGraph | None = None
        self.choice_critic: EnsembleCritic | None = None
        self.fallback_confidence = policy.fallback_confidence
        if actor is None:
            actor = policy.actor_ema if policy.predict_actor == "ema" else policy.actor
            fallback_actor = policy.fallback_actor_ema if policy.predict_actor == "ema" else policy.fallback_actor
            if fallback_actor is not None:
                self.fallback = DeterministicPolicyGraph(policy, fallback_actor)
                self.choice_critic = _exportable_critic(policy.critic)
        with th.no_grad():
            self.register_buffer("obs_mean", extractor.obs_mean.detach().cpu().float().clone())
            self.register_buffer("obs_std", extractor.obs_std.detach().cpu().float().clone())
            self.use_state_products = extractor.use_state_products
            self.register_buffer("idx_i", extractor.idx_i.detach().cpu().clone())
            self.register_buffer("idx_j", extractor.idx_j.detach().cpu().clone())
            plan = inference_plan(copy.deepcopy(actor).cpu().float(), copy_weights=True)
            for name in ("w_state_t", "b_in", "w_action_t", "time_proj", "w_last_t"):
                self.register_buffer(name, getattr(plan, name).detach().clone())
            # the hidden layers: (bias, W^T) pairs as buffers, activations as plain modules
            self.hidden_kinds: list[str] = []
            activations = []
            for i, layer in enumerate(plan.hidden):
                if isinstance(layer, tuple):
                    self.register_buffer(f"hidden_b{i}", layer[0].detach().clone())
                    self.register_buffer(f"hidden_w{i}", layer[1].detach().clone())
                    self.hidden_kinds.append("linear")
                else:
                    activations.append(_exportable_activation(layer))
                    self.hidden_kinds.append("activation")
            self.activations = nn.ModuleList(activations).requires_grad_(False)
            self.register_buffer("step_bias", th.stack([bias_t.detach().clone() for _, bias_t, *_ in plan.steps]))
            # n_action_samples > 1: the candidates' fixed chain noise [steps + 1, n, A] and the critics that rank them
            self.n_candidates = policy.n_action_samples
            self.critic: EnsembleCritic | None = None
            if self.n_candidates > 1:
                self.register_buffer("candidate_noise", policy.candidate_noise(actor).detach().cpu().float().clone())
                self.critic = _exportable_critic(policy.critic_target)
            # deterministic_rule="observation_noise" (one sample) or "mode" (mode_samples of them): the fixed
            # projection of the observation's noise
            self.observation_noise = self.n_candidates == 1 and policy.deterministic_rule in ("observation_noise", "mode")
            self.mode_samples = policy.mode_samples if self.n_candidates == 1 and policy.deterministic_rule == "mode" else 0
            self.mode_bandwidth = policy.mode_bandwidth
            if self.observation_noise:
                projection, offset = observation_noise_projection(
                    extractor.obs_mean.shape[0],
                    actor.n_diffusion_steps,
                    actor.action_dim * max(self.mode_samples, 1),
                    policy.predict_seed,
                )
                self.register_buffer("noise_projection", projection)
                self.register_buffer("noise_offset", offset)
            assert isinstance(policy.action_space, spaces.Box)
            self.register_buffer("action_low", th.as_tensor(policy.action_space.low, dtype=th.float32).flatten())
            self.register_buffer("action_high", th.as_tensor(policy.action_space.high, dtype=th.float32).flatten())
        # per step (alpha, c1 recip, c1, c2, sigma): Python floats, constants of the unrolled graph
        self.step_coefs = [(alpha, x_coef, coef1, coef2, sigma) for alpha, _, x_coef, coef1, coef2, sigma in plan.steps]
        self.obs_dim = int(self.obs_mean.shape[0])
        self.action_dim = actor.action_dim
        self.eval()

    @property
    def n_diffusion_steps(self) -> int:
        return len(self.step_coefs)

    def plan(self) -> InferencePlan:
        """The :class:`~sb3_pola.pola.fast_sampling.InferencePlan` of the held weights."""
        hidden: list[tuple[th.Tensor, th.Tensor] | Callable[[th.Tensor], th.Tensor]] = []
        activations = iter(self.activations)
        for i, kind in enumerate(self.hidden_kinds):
            if kind == "linear":
                hidden.append((getattr(self, f"hidden_b{i}"), getattr(self, f"hidden_w{i}")))
            else:
                hidden.append(next(activations))
        steps = [
            (alpha, self.step_bias[t], x_coef, coef1, coef2, sigma)
            for t, (alpha, x_coef, coef1, coef2, sigma) in enumerate(self.step_coefs)
        ]
        return InferencePlan(self.w_state_t, self.b_in, self.w_action_t, self.time_proj, hidden, self.w_last_t, steps)

    def forward(self, obs: th.Tensor) -> th.Tensor:
        x = (obs.float() - self.obs_mean) / self.obs_std  # [B, n]
        if self.use_state_products:
            x = th.cat((x, x[:, self.idx_i] * x[:, self.idx_j]), dim=-1)  # [B, n + n(n-1)/2]
        action = self._action(obs.float(), x)
        if self.fallback is not None:
            action = self._confident_choice(obs.float(), action, self.fallback._action(obs.float(), x))
        # SB3's unscale_action: [-1, 1] -> [low, high]
        return self.action_low + 0.5 * (action + 1.0) * (self.action_high - self.action_low)

    def _action(self, obs: th.Tensor, x: th.Tensor) -> th.Tensor:
        """The actor's action in ``[-1, 1]`` by the policy's rule, ``x`` the actor's state features."""
        if self.critic is not None:
            return self._best_candidate(obs, x)
        if self.mode_samples:
            return self._mode(obs, x)
        noise = None  # the noise-free chain from a_T = 0
        if self.observation_noise:  # the observation's own chain noise, as predict draws it
            noise = noise_from_projection(obs, self.noise_projection, self.noise_offset, self.n_diffusion_steps)
        return run_plan(self.plan(), x, noise)  # clipped to [-1, 1]

    def _confident_choice(self, obs: th.Tensor, action: th.Tensor, fallback: th.Tensor) -> th.Tensor:
        """``predict``'s confident choice (:meth:`~sb3_pola.pola.policies.POLAPolicy.confident_choice`)."""
        assert self.choice_critic is not None and self.fallback_confidence is not None
        q = self.choice_critic(th.cat([obs, obs]), th.cat([action, fallback]))  # [N, 2B]
        return choose_confident(q, action, fallback, self.fallback_confidence)

    def _mode(self, obs: th.Tensor, x: th.Tensor) -> th.Tensor:
        """``predict``'s mode rule: ``k`` chains per state with the observation's own noise, their kernel mode."""
        b, k, steps = obs.shape[0], self.mode_samples, self.n_diffusion_steps
        noise = noise_from_projection(obs, self.noise_projection, self.noise_offset, steps)  # [steps + 1, B, k A]
        noise = noise.reshape(steps + 1, b * k, self.action_dim)  # row b k + j: sample j of state b
        x_rep = x.unsqueeze(1).expand(b, k, x.shape[1]).reshape(b * k, x.shape[1])  # [B k, features]
        samples = run_plan(self.plan(), x_rep, noise).view(b, k, self.action_dim)  # [B, k, A]
        return kernel_mode(samples, self.mode_bandwidth)

    def _best_candidate(self, obs: th.Tensor, x: th.Tensor) -> th.Tensor:
        """``predict``'s Q-ranked rule: the chain for ``n`` candidates per state, the best by the pessimistic critic."""
        assert self.critic is not None
        b, n = obs.shape[0], self.n_candidates
        # rows ordered state by state, candidate within (predict's repeat_interleave); expand keeps ONNX's batch dynamic
        obs_rep = obs.unsqueeze(1).expand(b, n, obs.shape[1]).reshape(b * n, obs.shape[1])  # [B n, obs]
        x_rep = x.unsqueeze(1).expand(b, n, x.shape[1]).reshape(b * n, x.shape[1])  # [B n, features]
        steps = self.candidate_noise.shape[0]
        noise = self.candidate_noise.unsqueeze(1).expand(steps, b, n, self.action_dim).reshape(steps, b * n, self.action_dim)
        actions = run_plan(self.plan(), x_rep, noise)  # [B n, A]
        q = self.critic(obs_rep, actions).min(dim=0).values.view(b, n)  # [B, n]
        idx = q.argmax(dim=1).view(b, 1, 1).expand(b, 1, self.action_dim)
        return actions.view(b, n, self.action_dim).gather(1, idx).squeeze(1)  # [B, A]


def _exportable_critic(critic: EnsembleCritic) -> EnsembleCritic:
    """A CPU float32 copy of the target critics for the graph, its Mish modules as plain ``nn.Mish``."""
    critic = copy.deepcopy(critic).cpu().float().requires_grad_(False).eval()
    for i, layer in enumerate(critic.q_net):
        if isinstance(layer, (TwiceDifferentiableMish, FusedMish)):
            critic.q_net[i] = nn.Mish()
    return critic


def _exportable_activation(layer: Callable[[th.Tensor], th.Tensor]) -> nn.Module:
    """A plan's activation as a plain module: the no-grad chain's in-place Mish and the compiled one become ``nn.Mish``."""
    if layer is inference_mish or isinstance(layer, (FusedMish, nn.Mish)):
        return nn.Mish()
    if layer is th.relu_:
        return nn.ReLU()
    assert isinstance(layer, nn.Module), f"cannot export the activation {layer!r}"
    return copy.deepcopy(layer)


def check_exportable(policy: Any) -> None:
    """Raise :class:`PolicyExportError` if the static graph cannot reproduce ``policy``'s deterministic predict.

    :param policy: a :class:`~sb3_pola.pola.policies.POLAPolicy`
    """
    if not isinstance(policy, POLAPolicy):
        raise PolicyExportError(f"export_policy needs a POLAPolicy, got {type(policy).__name__}")
    # the graph reproduces these methods as written here; a subclass that overrides one may do anything
    overridden = [
        f"{cls.__name__}.{name}"
        for obj, cls, names in (
            (policy, POLAPolicy, ("_predict", "actor_features", "forward", "predict", "unscale_action")),
            (policy.features_extractor, StateProductsExtractor, ("forward", "normalize")),
            (policy.actor_ema if policy.predict_actor == "ema" else policy.actor, DiffusionActor, ("sample", "predict_noise")),
            # the Q-ranked rule also runs the target critics
            *(
                [(policy.critic_target, EnsembleCritic, ("forward", "inputs", "q_values"))]
                if policy.n_action_samples > 1
                else []
            ),
            # the confident choice runs the fallback actor and the critics
            *(
                [
                    (
                        policy.fallback_actor_ema if policy.predict_actor == "ema" else policy.fallback_actor,
                        DiffusionActor,
                        ("sample", "predict_noise"),
                    ),
                    (policy.critic, EnsembleCritic, ("forward", "inputs", "q_values")),
                ]
                if policy.fallback_actor is not None
                else []
            ),
        )
        if isinstance(obj, cls)
        for name in names
        if getattr(type(obj), name) is not getattr(cls, name)
    ]
    if not isinstance(policy.features_extractor, StateProductsExtractor):
        overridden.append(f"features extractor {type(policy.features_extractor).__name__}")
    if policy.n_action_samples > 1 and not isinstance(policy.critic_target, EnsembleCritic):
        overridden.append(f"critic {type(policy.critic_target).__name__}")
    if overridden:
        raise PolicyExportError(
            f"Cannot export {type(policy).__name__}: it overrides {', '.join(overridden)}, which the exported graph "
            "would not reproduce"
        )
    action_space = policy.action_space
    assert isinstance(action_space, spaces.Box)
    if not (np.all(np.isfinite(action_space.low)) and np.all(np.isfinite(action_space.high))):
        raise PolicyExportError(
            f"Cannot export a policy whose action space {action_space} has infinite bounds: predict rescales "
            "actions from [-1, 1] to the bounds"
        )


def _infer_format(path: str | os.PathLike[str]) -> str:
    return "torchscript" if pathlib.Path(path).suffix.lower() in TORCHSCRIPT_SUFFIXES else "onnx"


def export_policy(
    policy: POLAPolicy,
    path: str | os.PathLike[str],
    format: str = "onnx",
    opset_version: int | None = None,
    atol: float = 1e-5,
) -> pathlib.Path:
    """Write ``policy``'s deterministic action as an ONNX or TorchScript file (see the module docstring).

    The graph is checked against ``policy``'s own deterministic predict on a batch of observations drawn
    around the normalisation mean: before writing, and the written file too (TorchScript; ONNX where
    ``onnxruntime`` is installed).

    :param policy: the policy (``model.policy``)
    :param path: output file
    :param format: ``"onnx"`` (needs ``onnx`` and ``onnxscript``: ``pip install sb3_pola[export]``) or
        ``"torchscript"`` (a traced module for ``torch.jit.load``)
    :param opset_version: ONNX opset (``None``: the exporter's default)
    :param atol: largest absolute difference to ``predict`` tolerated by the check
    :raises PolicyExportError: the policy cannot be exported
    :return: the written file
    """
    if format not in EXPORT_FORMATS:
        raise ValueError(f"format must be one of {EXPORT_FORMATS}, got {format!r}")
    graph = DeterministicPolicyGraph(policy)
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    example = _probe_observations(graph, 8)
    with th.no_grad():
        expected = _predict_actions(policy, example)
        got = graph(example)
    _check_close(got, expected, atol, "The export graph")
    if format == "torchscript":
        with th.no_grad():
            traced = th.jit.trace(graph, (example,), check_trace=False)
            _check_close(traced(example), expected, atol, "The traced graph")
        th.jit.save(traced, str(path))
    else:
        _export_onnx(graph, example, path, opset_version)
        try:
            _check_onnx(path, example, expected, atol)
        except PolicyExportError:
            path.unlink()  # never leave a file that disagrees with predict
            raise
    return path


def _check_close(got: th.Tensor, expected: th.Tensor, atol: float, what: str) -> None:
    error = float((got - expected).abs().max())
    if not error <= atol:  # also catches NaN
        raise PolicyExportError(f"{what} differs from predict by {error:.3g} (> {atol}); this policy is not exportable as is")


def _check_onnx(path: pathlib.Path, example: th.Tensor, expected: th.Tensor, atol: float) -> None:
    """The written file under ONNX Runtime against ``predict``, where ONNX Runtime is installed."""
    try:
        import onnxruntime as ort
    except ImportError:
        return
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    actions = session.run(None, {INPUT_NAME: example.numpy()})[0]
    _check_close(th.as_tensor(actions), expected, atol, f"{path} under ONNX Runtime")


def _probe_observations(graph: DeterministicPolicyGraph, n: int) -> th.Tensor:
    """``[n, obs]`` observations around the data's mean (a fixed seed: the export is reproducible)."""
    generator = th.Generator().manual_seed(0)
    return graph.obs_mean + graph.obs_std * th.randn(n, graph.obs_dim, generator=generator)


def _predict_actions(policy: POLAPolicy, obs: th.Tensor) -> th.Tensor:
    """``policy.predict(obs, deterministic=True)`` as a float32 tensor (SB3's unscale in numpy, float32)."""
    actions = policy._predict(obs.to(policy.device), deterministic=True).cpu().numpy()
    return th.as_tensor(policy.unscale_action(actions))


def _export_onnx(graph: DeterministicPolicyGraph, example: th.Tensor, path: pathlib.Path, opset_version: int | None) -> None:
    try:
        import onnx  # noqa: F401
        import onnxscript  # noqa: F401
    except ImportError as error:
        raise ImportError(
            f"ONNX export needs the onnx and onnxscript packages ({error}): pip install 'sb3_pola[export]'"
        ) from error
    batch = th.export.Dim("batch")
    registry_logger = logging.getLogger("torch.onnx._internal.exporter._registration")
    level = registry_logger.level
    # the exporter's own noise: one warning per missing torchvision op, and a pytree deprecation inside torch
    registry_logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*LeafSpec.*", category=FutureWarning)
            program = th.onnx.export(
                graph,
                (example,),
                input_names=[INPUT_NAME],
                output_names=[OUTPUT_NAME],
                dynamic_shapes={INPUT_NAME: {0: batch}},
                opset_version=opset_version,
                dynamo=True,
                external_data=False,
                verbose=False,
            )
    finally:
        registry_logger.setLevel(level)
    assert program is not None
    program.save(str(path), external_data=False)
