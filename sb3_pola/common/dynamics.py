"""Probabilistic ensemble dynamics model ``p_psi(s', r | s, a)`` for POLA's look-ahead (paper, section IV).

The recipe is the one of MOPO / MOBILE / COMBO as in OfflineRL-Kit (our own code), split the same way:

- :class:`EnsembleDynamics` is the model: ``E`` Gaussian MLPs over ``[delta_s, r]`` evaluated as one set of
  batched matmuls, soft-bounded log-variances, the normalisation statistics and the elite members. Unlike
  those implementations, its prediction path (:meth:`EnsembleDynamics.step`) is pure torch and differentiable
  with respect to its inputs, so that the policy gradient can flow through ``s_{t+1} = p_psi(s_t, pi(s_t))``
  with the model's weights frozen.
- :class:`~sb3_pola.common.dynamics_trainer.DynamicsTrainer` (its own module) fits it: holdout split,
  normalisation statistics, bootstrap resamples and epochs, per-member holdout scores, early stopping and
  elite selection, each a small piece of its own.

Choices where the recipe is silent:

- Targets ``[delta_s, r]`` are standardised too (train-split mean/std), so that the likelihood weighs
  every dimension alike and the log-variance bounds (init ``[-10, 0.5]``) are in units of the target's
  variance. Early stopping and elite selection use the per-member holdout MSE in this normalised space
  (plus the holdout BCE when there is a termination head).
- All normalisation statistics and the elite indices are registered buffers: ``state_dict()`` carries
  them and loads with ``torch.load(weights_only=True)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch as th
import torch.nn.functional as F
from torch import nn

from sb3_pola.common.torch_layers import VectorizedLinear, vectorized_mlp
from sb3_pola.common.validation import check_choice, check_float, check_int, check_keys

# Per-layer L2 coefficients of the reference recipe (4 hidden layers + output layer).
DEFAULT_WEIGHT_DECAYS = (2.5e-5, 5e-5, 7.5e-5, 7.5e-5, 1e-4)


def default_weight_decays(n_layers: int) -> tuple[float, ...]:
    """The reference per-layer weight decays, extended to ``n_layers`` hidden layers.

    Hidden layer ``i`` gets ``(2.5e-5, 5e-5, 7.5e-5, 7.5e-5)[min(i, 3)]``, the output layer ``1e-4``;
    ``n_layers=4`` gives exactly :data:`DEFAULT_WEIGHT_DECAYS`.

    :param n_layers: number of hidden layers
    :return: ``n_layers + 1`` coefficients
    """
    hidden = DEFAULT_WEIGHT_DECAYS[:-1]
    return (*(hidden[min(i, len(hidden) - 1)] for i in range(n_layers)), DEFAULT_WEIGHT_DECAYS[-1])


MEAN_LOSSES = ("nll", "beta_nll", "mse")
# the arguments of EnsembleDynamics a user sets (obs_dim and action_dim come from the data)
DYNAMICS_KWARGS = (
    "n_members",
    "n_elites",
    "hidden_dim",
    "n_layers",
    "learn_termination",
    "weight_decays",
    "mean_loss",
    "beta",
)


def check_dynamics_kwargs(kwargs: dict, name: str = "dynamics_kwargs") -> None:
    """Check the user's arguments of :class:`EnsembleDynamics` (before anything is built), naming them as
    ``dynamics_kwargs['n_members']``.

    :param kwargs: the arguments
    :param name: the name of the dict in the messages
    :raises ~sb3_pola.common.errors.HyperparameterError: an unknown key or a value out of range
    """
    check_keys(name, kwargs, DYNAMICS_KWARGS)
    n_members = check_int(f"{name}['n_members']", kwargs.get("n_members", 7), low=1)
    check_int(f"{name}['n_elites']", kwargs.get("n_elites", 5), low=1, high=n_members)
    check_int(f"{name}['hidden_dim']", kwargs.get("hidden_dim", 200), low=1)
    check_int(f"{name}['n_layers']", kwargs.get("n_layers", 4), low=1)
    check_choice(f"{name}['mean_loss']", kwargs.get("mean_loss", "beta_nll"), MEAN_LOSSES)
    check_float(f"{name}['beta']", kwargs.get("beta", 0.5), low=0.0, high=1.0)


@dataclass(frozen=True)
class NormalizationStats:
    """Column means and stds of the inputs ``[s, a]`` and the targets ``[s' - s, r]`` (float32).

    :param input_mean: ``[obs_dim + action_dim]``
    :param input_std: ``[obs_dim + action_dim]``
    :param target_mean: ``[obs_dim + 1]``
    :param target_std: ``[obs_dim + 1]``
    """

    input_mean: th.Tensor
    input_std: th.Tensor
    target_mean: th.Tensor
    target_std: th.Tensor


class EnsembleDynamics(nn.Module):
    """Ensemble of Gaussian MLPs over ``[delta_state, reward]`` (+ optional termination logit).

    Each member maps the standardised ``(s, a)`` to a Gaussian over the standardised ``[s' - s, r]``;
    ``s' = s + delta_s``. The log-variance is soft-bounded between learnable ``min_logvar`` (init -10)
    and ``max_logvar`` (init 0.5), shared by the members. With ``learn_termination=True`` one more output
    is a Bernoulli logit of ``done``, trained with BCE (for environments without a known rule).

    :param obs_dim: observation size
    :param action_dim: action size
    :param n_members: ensemble size ``E``
    :param n_elites: number of elite members (best holdout error) used by :meth:`step`
    :param hidden_dim: width of every hidden layer
    :param n_layers: number of hidden layers (SiLU / Swish activations)
    :param learn_termination: add a termination logit head trained on ``dones``
    :param weight_decays: L2 coefficient per linear layer (``n_layers + 1`` values); default
        :func:`default_weight_decays` (2.5e-5, 5e-5, 7.5e-5, 7.5e-5, 1e-4 for 4 hidden layers)
    :param mean_loss: how the Gaussian mean is fitted. ``"nll"`` (MOPO): the heteroscedastic NLL, which
        lets a member give up on the mean of hard dimensions by raising their variance; ``"beta_nll"``
        (default; Seitzer et al., 2022): the NLL of every element weighted by its detached variance to the power
        ``beta``, which restores the mean's gradient there; ``"mse"``: the mean by squared error and
        the variance by the NLL with the mean detached. ``beta_nll`` is the default because under the plain
        NLL the holdout error of the mean rose while the NLL fell, so early stopping kept a barely trained model
        (k-step errors of the three in docs/results.md, "The dynamics fit")
    :param beta: the exponent of ``"beta_nll"`` (0 is the NLL, 1 gives the mean an MSE gradient)
    """

    elites: th.Tensor
    obs_mean: th.Tensor
    obs_std: th.Tensor
    act_mean: th.Tensor
    act_std: th.Tensor
    target_mean: th.Tensor
    target_std: th.Tensor

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        n_members: int = 7,
        n_elites: int = 5,
        hidden_dim: int = 200,
        n_layers: int = 4,
        learn_termination: bool = False,
        weight_decays: Sequence[float] | None = None,
        mean_loss: str = "beta_nll",
        beta: float = 0.5,
    ) -> None:
        super().__init__()
        if mean_loss not in MEAN_LOSSES:
            raise ValueError(f"mean_loss must be one of {MEAN_LOSSES}, got {mean_loss!r}")
        self.mean_loss = mean_loss
        self.beta = beta
        if not 1 <= n_elites <= n_members:
            raise ValueError(f"need 1 <= n_elites <= n_members, got n_elites={n_elites}, n_members={n_members}")
        self.obs_dim = obs_dim
        self.action_dim = action_dim
        self.n_members = n_members
        self.n_elites = n_elites
        self.learn_termination = learn_termination
        self.target_dim = obs_dim + 1  # [delta_s, r]
        out_dim = 2 * self.target_dim + int(learn_termination)  # [mean, raw logvar, (logit)]
        self.net = vectorized_mlp(obs_dim + action_dim, out_dim, [hidden_dim] * n_layers, n_members, nn.SiLU)
        decays = default_weight_decays(n_layers) if weight_decays is None else tuple(float(w) for w in weight_decays)
        if len(decays) != n_layers + 1:
            raise ValueError(f"weight_decays needs {n_layers + 1} values (one per linear layer), got {len(decays)}")
        self.weight_decays = decays
        self.max_logvar = nn.Parameter(th.full((self.target_dim,), 0.5))
        self.min_logvar = nn.Parameter(th.full((self.target_dim,), -10.0))
        # Normalisation statistics (train split) and elites: buffers, so the state_dict carries them.
        self.register_buffer("obs_mean", th.zeros(obs_dim))
        self.register_buffer("obs_std", th.ones(obs_dim))
        self.register_buffer("act_mean", th.zeros(action_dim))
        self.register_buffer("act_std", th.ones(action_dim))
        self.register_buffer("target_mean", th.zeros(self.target_dim))
        self.register_buffer("target_std", th.ones(self.target_dim))
        self.register_buffer("elites", th.arange(n_elites, dtype=th.long))

    @property
    def linear_layers(self) -> list[VectorizedLinear]:
        """The ``n_layers + 1`` ensemble linear layers, input to output."""
        return [m for m in self.net if isinstance(m, VectorizedLinear)]

    def normalize_inputs(self, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """Standardised ``[s, a]``.

        :param obs: observations ``[..., obs_dim]``
        :param actions: actions ``[..., action_dim]``
        :return: ``[..., obs_dim + action_dim]``
        """
        obs_n = (obs.float() - self.obs_mean) / self.obs_std
        act_n = (actions.float() - self.act_mean) / self.act_std
        return th.cat((obs_n, act_n), dim=-1)

    def _forward(self, x: th.Tensor, members: th.Tensor | None = None) -> tuple[th.Tensor, th.Tensor, th.Tensor | None]:
        """Members' outputs in the normalised target space.

        :param x: standardised inputs ``[E', B, in]``, ``E' = E`` or ``len(members)``
        :param members: indices of the members to evaluate (``None``: all of them)
        :return: mean ``[E', B, D]``, bounded log-variance ``[E', B, D]``, termination logit ``[E', B]`` or None
        """
        for module in self.net:
            if members is not None and isinstance(module, VectorizedLinear):
                # [E', B, in] @ [E', in, out] + [E', 1, out]: the selected members only
                x = th.baddbmm(module.bias.index_select(0, members), x, module.weight.index_select(0, members))
            else:
                x = module(x)
        d = self.target_dim
        mean = x[..., :d]
        logvar = self.max_logvar - F.softplus(self.max_logvar - x[..., d : 2 * d])
        logvar = self.min_logvar + F.softplus(logvar - self.min_logvar)
        logit = x[..., 2 * d] if self.learn_termination else None
        return mean, logvar, logit

    def forward(self, obs: th.Tensor, actions: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor | None]:
        """All members, in the normalised target space (what the loss sees).

        :param obs: observations ``[B, obs_dim]``
        :param actions: actions ``[B, action_dim]``
        :return: mean ``[E, B, D]``, log-variance ``[E, B, D]``, termination logit ``[E, B]`` or None
            (``D = obs_dim + 1``; denormalise with ``target_mean`` / ``target_std``)
        """
        x = self.normalize_inputs(obs, actions)  # [B, in]
        return self._forward(x.unsqueeze(0).expand(self.n_members, -1, -1))  # [E, B, in]

    def step(
        self, obs: th.Tensor, actions: th.Tensor, deterministic: bool = True
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
        """One model step ``(s, a) -> (s', r, P(done), u)`` with the elite members, differentiable w.r.t. the inputs.

        ``deterministic=True``: the mean over the elites' Gaussian means. ``deterministic=False``: every
        sample uses a uniformly drawn elite and a reparameterised Gaussian sample ``mu + sigma * eps``.
        No host-device sync and no data-dependent branching (CUDA-graph friendly).

        :param obs: observations ``[B, obs_dim]``
        :param actions: actions ``[B, action_dim]``
        :param deterministic: mean prediction instead of a sample
        :return: next observations ``[B, obs_dim]``, rewards ``[B]``, termination probabilities ``[B]``
            (zeros without a termination head) and the elites' disagreement ``u`` ``[B]``: the RMS over state
            dimensions of the standard deviation of the elites' mean state changes, in standardised units
            (the epistemic doubt MOPO-style penalties use; 0 with a single elite)
        """
        x = self.normalize_inputs(obs, actions)  # [B, in]
        batch = x.shape[0]
        x = x.unsqueeze(0).expand(self.n_elites, -1, -1)  # [K, B, in]
        mean, logvar, logit = self._forward(x, self.elites)  # [K, B, D]
        if self.n_elites > 1:
            disagreement = mean[..., : self.obs_dim].std(dim=0).pow(2).mean(dim=-1).sqrt()  # [B]
        else:
            disagreement = mean.new_zeros(batch)
        if deterministic:
            target = mean.mean(dim=0)  # [B, D]
            term_prob = th.sigmoid(logit).mean(dim=0) if logit is not None else None  # [B]
        else:
            pick = th.randint(self.n_elites, (batch,), device=x.device)  # [B] elite per sample
            rows = th.arange(batch, device=x.device)
            mu = mean[pick, rows]  # [B, D]
            std = (0.5 * logvar[pick, rows]).exp()
            target = mu + std * th.randn_like(mu)
            term_prob = th.sigmoid(logit[pick, rows]) if logit is not None else None
        target = target * self.target_std + self.target_mean  # raw [delta_s, r]
        next_obs = obs + target[:, : self.obs_dim]
        reward = target[:, self.obs_dim]
        if term_prob is None:
            term_prob = th.zeros_like(reward)
        return next_obs, reward, term_prob, disagreement

    def freeze(self) -> EnsembleDynamics:
        """Stop gradients to the parameters (eval mode); gradients still flow to the inputs of :meth:`step`.

        :return: self
        """
        self.requires_grad_(False)
        self.eval()
        return self

    @th.no_grad()
    def set_normalization(self, stats: NormalizationStats) -> None:
        """Standardise inputs and targets with these statistics from now on.

        :param stats: statistics of the training split (:func:`~sb3_pola.common.dynamics_data.split_statistics`)
        """
        self.obs_mean.copy_(stats.input_mean[: self.obs_dim])
        self.obs_std.copy_(stats.input_std[: self.obs_dim])
        self.act_mean.copy_(stats.input_mean[self.obs_dim :])
        self.act_std.copy_(stats.input_std[self.obs_dim :])
        self.target_mean.copy_(stats.target_mean)
        self.target_std.copy_(stats.target_std)

    @th.no_grad()
    def set_elites(self, elites: th.Tensor) -> None:
        """Make these members the ones :meth:`step` uses.

        :param elites: member indices ``[n_elites]``
        """
        self.elites.copy_(elites)

    def _loss(
        self, mean: th.Tensor, logvar: th.Tensor, logit: th.Tensor | None, y: th.Tensor, done: th.Tensor | None
    ) -> th.Tensor:
        """Gaussian NLL (or its ``mean_loss`` form) summed over members + L2 weight decay + log-variance bounds (+ BCE).

        :param mean: members' means in the normalised target space ``[E, b, D]``
        :param logvar: their bounded log-variances ``[E, b, D]``
        :param logit: termination logits ``[E, b]`` or None
        :param y: standardised targets ``[E, b, D]``
        :param done: termination flags ``[E, b]`` or None
        :return: the scalar training loss
        """
        inv_var = th.exp(-logvar)
        sq_err = (mean - y) ** 2  # [E, b, D]
        if self.mean_loss == "nll":
            elementwise = sq_err * inv_var + logvar
        elif self.mean_loss == "beta_nll":
            elementwise = (sq_err * inv_var + logvar) * logvar.detach().mul(self.beta).exp()
        else:  # "mse": the mean by squared error, the variance by the NLL of the detached mean
            elementwise = sq_err + (sq_err.detach() * inv_var + logvar)
        loss = elementwise.mean(dim=(1, 2)).sum()
        for layer, decay in zip(self.linear_layers, self.weight_decays, strict=True):
            loss = loss + decay * 0.5 * layer.weight.pow(2).sum()
        loss = loss + 0.01 * (self.max_logvar.sum() - self.min_logvar.sum())
        if logit is not None and done is not None:
            loss = loss + F.binary_cross_entropy_with_logits(logit, done, reduction="none").mean(dim=1).sum()
        return loss
