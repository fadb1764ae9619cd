"""Probabilistic ensemble dynamics model ``p_psi(s', r | s, a)`` for POLA's look-ahead (paper, section IV).

The recipe is the one of MOPO / MOBILE / COMBO as in OfflineRL-Kit (our own code): ``E`` Gaussian MLPs over
``[delta_s, r]`` evaluated as one set of batched matmuls, soft-bounded log-variances, bootstrap resamples,
holdout early stopping and elite selection. Unlike those implementations, the prediction path (:meth:`step`)
is pure torch and differentiable with respect to its inputs, so that the policy gradient can flow through
``s_{t+1} = p_psi(s_t, pi(s_t))`` with the model's weights frozen.

Choices where the recipe is silent:

- Targets ``[delta_s, r]`` are standardised too (train-split mean/std), so that the likelihood weighs
  every dimension alike and the log-variance bounds (init ``[-10, 0.5]``) are in units of the target's
  variance. Early stopping and elite selection use the per-member holdout MSE in this normalised space
  (plus the holdout BCE when there is a termination head).
- All normalisation statistics and the elite indices are registered buffers: ``state_dict()`` carries
  them and loads with ``torch.load(weights_only=True)``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import torch as th
import torch.nn.functional as F
from torch import nn

from sb3_pola.common.torch_layers import VectorizedLinear, vectorized_mlp

if TYPE_CHECKING:
    from stable_baselines3.common.logger import Logger

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


def _split_statistics(
    obs: th.Tensor, act: th.Tensor, next_obs: th.Tensor, rew: th.Tensor, rows: th.Tensor, chunk_size: int = 4096
) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
    """Column mean and std of the inputs ``[s, a]`` and the targets ``[s' - s, r]`` over the transitions ``rows``.

    The std is the unbiased one, with 1 for (near-)constant columns and for a single row. The split is gathered
    chunk by chunk (never copied whole); the chunks' float32 moments are merged in float64 with Chan et al.'s
    pairwise update, so the result equals the float32 statistics of the materialised split up to rounding.

    :param obs: ``[N, obs_dim]``
    :param act: ``[N, action_dim]``
    :param next_obs: ``[N, obs_dim]``
    :param rew: ``[N, 1]``
    :param rows: indices of the split ``[M]``
    :param chunk_size: rows gathered at a time (small: large temporaries of a loop leave glibc's heap grown)
    :return: input mean and std ``[obs_dim + action_dim]``, target mean and std ``[obs_dim + 1]`` (float32)
    """
    n_in = obs.shape[1] + act.shape[1]
    count = 0
    mean = th.zeros(n_in + obs.shape[1] + 1, dtype=th.float64, device=obs.device)
    m2 = th.zeros_like(mean)  # sum of squared deviations from the mean
    for start in range(0, rows.shape[0], chunk_size):
        idx = rows[start : start + chunk_size]
        obs_rows = obs.index_select(0, idx)
        chunk = th.cat(
            (obs_rows, act.index_select(0, idx), next_obs.index_select(0, idx) - obs_rows, rew.index_select(0, idx)), dim=-1
        )  # [c, in + D]
        c = chunk.shape[0]
        c_var, c_mean_32 = th.var_mean(chunk, dim=0, correction=0)
        c_mean, c_m2 = c_mean_32.double(), c_var.double() * c
        delta = c_mean - mean
        total = count + c
        mean = mean + delta * (c / total)
        m2 = m2 + c_m2 + delta**2 * (count * c / total)
        count = total
    if count > 1:
        std = (m2 / (count - 1)).sqrt().float()
        std = th.where(std < 1e-6, th.ones_like(std), std)
    else:
        std = th.ones_like(mean, dtype=th.float32)
    mean = mean.float()
    return mean[:n_in], std[:n_in], mean[n_in:], std[n_in:]


MEAN_LOSSES = ("nll", "beta_nll", "mse")


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
        (Seitzer et al., 2022): the NLL of every element weighted by its detached variance to the power
        ``beta``, which restores the mean's gradient there; ``"mse"``: the mean by squared error and
        the variance by the NLL with the mean detached
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
        mean_loss: str = "nll",
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

    def _loss(
        self, mean: th.Tensor, logvar: th.Tensor, logit: th.Tensor | None, y: th.Tensor, done: th.Tensor | None
    ) -> th.Tensor:
        """Gaussian NLL (or its ``mean_loss`` form) summed over members + L2 weight decay + log-variance bounds (+ BCE)."""
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

    @th.no_grad()
    def _holdout_scores(self, x: th.Tensor, y: th.Tensor, done: th.Tensor | None) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """Per-member holdout error.

        :param x: standardised holdout inputs ``[H, in]``
        :param y: standardised holdout targets ``[H, D]``
        :param done: holdout termination flags ``[H]`` or None
        :return: normalised-target MSE ``[E]``, the early-stopping score ``[E]`` (MSE + BCE with a head)
            and the raw next-state MSE ``[E]``
        """
        mean, _, logit = self._forward(x.unsqueeze(0).expand(self.n_members, -1, -1))  # [E, H, D]
        err = mean - y  # [E, H, D]
        mse = (err**2).mean(dim=(1, 2))  # [E]
        raw_state_mse = ((err * self.target_std)[..., : self.obs_dim] ** 2).mean(dim=(1, 2))  # [E]
        score = mse
        if logit is not None and done is not None:
            score = mse + F.binary_cross_entropy_with_logits(logit, done.expand_as(logit), reduction="none").mean(dim=1)
        return mse, score, raw_state_mse

    def fit(
        self,
        observations: th.Tensor | np.ndarray,
        actions: th.Tensor | np.ndarray,
        next_observations: th.Tensor | np.ndarray,
        rewards: th.Tensor | np.ndarray,
        dones: th.Tensor | np.ndarray | None = None,
        *,
        batch_size: int = 256,
        learning_rate: float = 1e-3,
        holdout_ratio: float = 0.2,
        max_holdout: int = 1000,
        max_epochs: int | None = None,
        max_steps: int | None = None,
        patience: int = 5,
        progress_bar: bool = False,
        logger: Logger | None = None,
        verbose: int = 0,
        max_epoch_steps: int | None = 1000,
    ) -> dict[str, float]:
        """Train the ensemble on transitions, with holdout early stopping, then pick the elites.

        A random ``min(holdout_ratio * N, max_holdout)`` transitions are held out; normalisation statistics
        come from the rest. Every member trains on its own bootstrap resample of the training split (fixed
        for the whole fit), all members in one batched forward per Adam step. An *epoch* is one pass over
        the resample, capped at ``max_epoch_steps`` gradient steps (so that 1M transitions give epochs of
        1000 steps, not 3,900); after every epoch each member's holdout MSE is measured, a member whose MSE
        improved by more than 1% keeps a snapshot of its weights, and training stops after ``patience``
        epochs without such an improvement of any member (or at ``max_epochs`` / ``max_steps``). Each member
        ends with its best weights; the ``n_elites`` best holdout members become the elites.
        Memory: the data are not copied (float32 tensors on the model's device are used as they are); the fit keeps
        index tensors (int32 split permutation and ``[E, N]`` bootstrap) and gathers and standardises each minibatch
        from the caller's tensors, which it never modifies.
        All randomness comes from torch's global RNG: ``th.manual_seed`` makes a fit reproducible.
        ``fit`` makes the parameters trainable again (undoes :meth:`freeze`) and leaves the model in eval mode.

        :param observations: ``[N, obs_dim]``
        :param actions: ``[N, action_dim]``
        :param next_observations: ``[N, obs_dim]`` (the episode's own next observations)
        :param rewards: ``[N]``
        :param dones: ``[N]`` termination flags, true terminations only, not time-limit truncations
            (needed with ``learn_termination``, ignored otherwise)
        :param batch_size: minibatch size per member
        :param learning_rate: Adam learning rate
        :param holdout_ratio: fraction of the data held out for early stopping
        :param max_holdout: maximum holdout size
        :param max_epochs: stop after this many epochs (``None``: early stopping only)
        :param max_steps: stop after this many gradient steps in total (``None``: no limit)
        :param patience: epochs without a >1% improvement of any member before stopping
        :param progress_bar: show a tqdm bar over epochs
        :param logger: SB3 logger; ``dynamics/*`` values are recorded and dumped after every epoch
        :param verbose: 1: a summary line at the end, 2: a line per epoch
        :param max_epoch_steps: cap on the gradient steps of one epoch (``None``: a full pass)
        :return: ``holdout_mse`` (raw next-state MSE of the deterministic elite-mean prediction on the
            holdout), ``no_change_mse`` (same for ``s' = s``), ``holdout_reward_mse``, ``holdout_norm_mse``
            (elites' mean normalised-target MSE), ``holdout_term_acc`` (with a termination head),
            ``train_loss``, ``epochs``, ``steps``, ``fit_time`` (seconds)
        """
        start = time.perf_counter()
        if self.learn_termination and dones is None:
            raise ValueError("learn_termination=True needs dones")
        device = self.obs_mean.device

        def as_tensor(a: th.Tensor | np.ndarray) -> th.Tensor:
            return th.as_tensor(a, dtype=th.float32, device=device)

        obs = as_tensor(observations).reshape(-1, self.obs_dim)
        n = obs.shape[0]
        act = as_tensor(actions).reshape(n, self.action_dim)
        next_obs = as_tensor(next_observations).reshape(n, self.obs_dim)
        rew = as_tensor(rewards).reshape(n, 1)
        done_all = as_tensor(dones).reshape(n) if (self.learn_termination and dones is not None) else None

        # Holdout split; with no room for one, evaluate on (part of) the training data. Only indices are
        # kept (int32 where they fit: same draws as int64): minibatches are gathered from the caller's tensors.
        n_holdout = min(int(n * holdout_ratio), max_holdout)
        if n - n_holdout < 1:
            raise ValueError(f"not enough transitions to fit ({n})")
        index_dtype = th.int32 if n <= th.iinfo(th.int32).max else th.long
        perm = th.randperm(n, device=device, dtype=index_dtype)
        hold_idx, train_idx = perm[:n_holdout].long(), perm[n_holdout:]  # train_idx: a view, no copy
        if n_holdout == 0:
            hold_idx = train_idx[:max_holdout].long()

        in_mean, in_std, t_mean, t_std = _split_statistics(obs, act, next_obs, rew, train_idx)
        with th.no_grad():
            self.obs_mean.copy_(in_mean[: self.obs_dim])
            self.obs_std.copy_(in_std[: self.obs_dim])
            self.act_mean.copy_(in_mean[self.obs_dim :])
            self.act_std.copy_(in_std[self.obs_dim :])
            self.target_mean.copy_(t_mean)
            self.target_std.copy_(t_std)

        def gather(rows: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
            """Standardised inputs ``[..., in]`` and targets ``[..., D]`` of the transitions ``rows``."""
            obs_rows = obs[rows]
            x = (th.cat((obs_rows, act[rows]), dim=-1) - in_mean) / in_std
            y = (th.cat((next_obs[rows] - obs_rows, rew[rows]), dim=-1) - t_mean) / t_std
            return x, y

        x_hold, y_hold = gather(hold_idx)  # [H, in], [H, D]
        d_hold = done_all[hold_idx] if done_all is not None else None
        no_change_mse = float(((next_obs[hold_idx] - obs[hold_idx]) ** 2).mean())

        n_train = train_idx.shape[0]
        steps_per_pass = math.ceil(n_train / batch_size)
        steps_per_epoch = steps_per_pass if max_epoch_steps is None else max(1, min(steps_per_pass, max_epoch_steps))
        # Bootstrap resample per member, fixed for the fit: [E, N_train] indices into the training split
        # (drawn in place in the index dtype: the same values as th.randint's int64).
        bootstrap = th.empty((self.n_members, n_train), dtype=index_dtype, device=device).random_(0, n_train)
        pass_perm = th.empty(0, dtype=index_dtype, device=device)
        cursor = steps_per_pass  # forces a shuffle at the first step

        self.requires_grad_(True)
        self.train()
        optimizer = th.optim.Adam(self.parameters(), lr=learning_rate)
        member_params = [p for layer in self.linear_layers for p in (layer.weight, layer.bias)]
        snapshots = [p.detach().clone() for p in member_params]
        best = th.full((self.n_members,), float("inf"), device=device)

        pbar = None
        if progress_bar:
            from tqdm.auto import tqdm

            pbar = tqdm(total=max_epochs, desc="dynamics", unit="epoch")

        epoch, step, epochs_since_improvement = 0, 0, 0
        train_loss = float("nan")
        while (max_epochs is None or epoch < max_epochs) and (max_steps is None or step < max_steps):
            n_steps = steps_per_epoch if max_steps is None else min(steps_per_epoch, max_steps - step)
            loss_sum = th.zeros((), device=device)
            for _ in range(n_steps):
                if cursor >= steps_per_pass:
                    # New pass: one column permutation shuffles every member's (independent) resample.
                    pass_perm = th.randperm(n_train, device=device, dtype=index_dtype)
                    cursor = 0
                cols = pass_perm[cursor * batch_size : (cursor + 1) * batch_size]  # [b]
                rows = train_idx[bootstrap[:, cols].long()].long()  # [E, b] transitions
                cursor += 1
                x, y = gather(rows)  # [E, b, in], [E, b, D]
                mean, logvar, logit = self._forward(x)  # [E, b, D]
                loss = self._loss(mean, logvar, logit, y, done_all[rows] if done_all is not None else None)
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                optimizer.step()
                loss_sum += loss.detach()
            step += n_steps
            epoch += 1
            train_loss = float(loss_sum) / max(n_steps, 1)

            # Early stopping on each member's holdout error; keep each member's best weights.
            mse, score, raw_state_mse = self._holdout_scores(x_hold, y_hold, d_hold)  # [E]
            improved = score < best * 0.99  # relative improvement > 1%
            best = th.where(improved, score, best)
            with th.no_grad():
                for snap, p in zip(snapshots, member_params, strict=True):
                    snap.copy_(th.where(improved.view(-1, 1, 1), p, snap))
            epochs_since_improvement = 0 if bool(improved.any()) else epochs_since_improvement + 1

            record = {
                "dynamics/train_loss": train_loss,
                "dynamics/holdout_mse": float(raw_state_mse.mean()),  # members' mean, raw next state
                "dynamics/no_change_mse": no_change_mse,
                "dynamics/holdout_norm_mse": float(mse.mean()),
                "dynamics/best_holdout_norm_mse": float(best.min()),
                "dynamics/epoch": epoch,
                "dynamics/steps": step,
            }
            if logger is not None:
                for key, value in record.items():
                    logger.record(key, value)
                logger.dump(step=step)
            if verbose >= 2:
                print(
                    f"dynamics epoch {epoch} steps {step}: train loss {train_loss:.4f}, "
                    f"holdout next-state mse {float(raw_state_mse.mean()):.5f} (no change {no_change_mse:.5f}), "
                    f"normalised {float(mse.mean()):.5f} (best {float(best.min()):.5f}), "
                    f"no improvement for {epochs_since_improvement}"
                )
            if pbar is not None:
                pbar.update(1)
                pbar.set_postfix(loss=f"{train_loss:.3f}", holdout=f"{float(mse.mean()):.4f}")
            if epochs_since_improvement >= patience:
                break
        if pbar is not None:
            pbar.close()
        optimizer.zero_grad(set_to_none=True)  # leave no stale gradients on the parameters

        # Best weights of every member, then the elites.
        with th.no_grad():
            for snap, p in zip(snapshots, member_params, strict=True):
                p.copy_(snap)
        mse, score, _ = self._holdout_scores(x_hold, y_hold, d_hold)
        with th.no_grad():
            self.elites.copy_(th.sort(th.argsort(score)[: self.n_elites]).values)
        self.eval()

        metrics = self._evaluate(obs[hold_idx], act[hold_idx], next_obs[hold_idx], rew[hold_idx, 0], d_hold)
        metrics.update(
            holdout_norm_mse=float(mse[self.elites].mean()),
            train_loss=train_loss,
            epochs=float(epoch),
            steps=float(step),
            fit_time=time.perf_counter() - start,
        )
        if logger is not None:
            for key, value in metrics.items():
                logger.record(f"dynamics/{key}", value)
            logger.dump(step=step)
        if verbose >= 1:
            print(
                f"dynamics fit: {epoch} epochs, {step} steps, {metrics['fit_time']:.1f} s; holdout next-state mse "
                f"{metrics['holdout_mse']:.5f} vs no-change {metrics['no_change_mse']:.5f}, "
                f"reward mse {metrics['holdout_reward_mse']:.5f}, elites {self.elites.tolist()}"
            )
        return metrics

    @th.no_grad()
    def _evaluate(
        self, obs: th.Tensor, act: th.Tensor, next_obs: th.Tensor, rew: th.Tensor, done: th.Tensor | None
    ) -> dict[str, float]:
        """Raw-space errors of the deterministic :meth:`step` on held-out transitions."""
        pred_obs, pred_rew, pred_term, _ = self.step(obs, act, deterministic=True)
        metrics = {
            "holdout_mse": float(((pred_obs - next_obs) ** 2).mean()),
            "no_change_mse": float(((obs - next_obs) ** 2).mean()),
            "holdout_reward_mse": float(((pred_rew - rew) ** 2).mean()),
        }
        if done is not None:
            metrics["holdout_term_acc"] = float(((pred_term > 0.5).float() == done).float().mean())
        return metrics
