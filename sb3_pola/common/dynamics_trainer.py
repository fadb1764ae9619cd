"""The trainer of :class:`~sb3_pola.common.dynamics.EnsembleDynamics` (MOPO / OfflineRL-Kit recipe, our own code).

:class:`DynamicsTrainer` owns the optimiser and the fit: holdout split, normalisation statistics of the training
split and bootstrap resamples (:mod:`sb3_pola.common.dynamics_data`), epochs, per-member holdout scores
(:func:`holdout_scores`), early stopping (:class:`EarlyStopping`) and elite selection (:func:`select_elites`). The
model module knows nothing of it::

    dynamics = EnsembleDynamics(obs_dim, action_dim)
    info = DynamicsTrainer(dynamics, max_epochs=50).fit(obs, actions, next_obs, rewards, dones)
"""

from __future__ import annotations

import math
import time
import warnings
from typing import TYPE_CHECKING

import numpy as np
import torch as th
import torch.nn.functional as F

from sb3_pola.common.dynamics import EnsembleDynamics, NormalizationStats
from sb3_pola.common.dynamics_data import BootstrapBatches, Transitions, holdout_split, split_statistics
from sb3_pola.common.validation import check_float, check_int, check_keys

if TYPE_CHECKING:
    from stable_baselines3.common.logger import Logger
    from tqdm import tqdm


# the arguments of DynamicsTrainer a user sets through POLA's dynamics_fit_kwargs
FIT_KWARGS = (
    "batch_size",
    "learning_rate",
    "holdout_ratio",
    "max_holdout",
    "max_epochs",
    "max_steps",
    "patience",
    "max_epoch_steps",
    "progress_bar",
    "logger",
    "verbose",
)


# the fit's budget when none is given (POLA's default): this many passes over the data, and at least MIN_AUTO_STEPS
# gradient steps; early stopping ends most fits of large datasets before it (1M transitions: 3 epochs of 1000 steps)
AUTO_PASSES = 10
MIN_AUTO_STEPS = 1000


def auto_max_steps(n_transitions: int, batch_size: int = 256, holdout_ratio: float = 0.2, max_holdout: int = 1000) -> int:
    """A fit's step budget sized to the data: :data:`AUTO_PASSES` passes over the training split, at least
    :data:`MIN_AUTO_STEPS` steps (30k transitions: 1,140 steps, about 40 s of the default ensemble on one CPU core).

    :param n_transitions: the dataset's transitions
    :param batch_size: the fit's minibatch size
    :param holdout_ratio: the fit's holdout fraction
    :param max_holdout: the fit's maximum holdout size
    :return: the ``max_steps`` of the fit
    """
    n_train = n_transitions - min(int(n_transitions * holdout_ratio), max_holdout)
    return max(MIN_AUTO_STEPS, AUTO_PASSES * math.ceil(max(n_train, 1) / batch_size))


def check_fit_kwargs(kwargs: dict, name: str = "dynamics_fit_kwargs") -> None:
    """Check arguments of :class:`DynamicsTrainer`, naming them as ``dynamics_fit_kwargs['patience']``.

    :param kwargs: the arguments
    :param name: the name of the dict in the messages (``""``: the bare argument names)
    :raises ~sb3_pola.common.errors.HyperparameterError: an unknown key or a value out of range
    """

    def key(arg: str) -> str:
        return f"{name}[{arg!r}]" if name else arg

    if name:
        check_keys(name, kwargs, FIT_KWARGS)
    check_int(key("batch_size"), kwargs.get("batch_size", 1), low=1)
    check_float(key("learning_rate"), kwargs.get("learning_rate", 1e-3), low=0.0, low_open=True)
    check_float(key("holdout_ratio"), kwargs.get("holdout_ratio", 0.2), low=0.0, high=1.0, high_open=True)
    check_int(key("max_holdout"), kwargs.get("max_holdout", 1), low=1)
    check_int(key("max_epochs"), kwargs.get("max_epochs"), low=1, optional=True)
    check_int(key("max_steps"), kwargs.get("max_steps"), low=1, optional=True)
    check_int(key("patience"), kwargs.get("patience", 1), low=1)
    check_int(key("max_epoch_steps"), kwargs.get("max_epoch_steps"), low=1, optional=True)


@th.no_grad()
def holdout_scores(
    model: EnsembleDynamics, x: th.Tensor, y: th.Tensor, done: th.Tensor | None
) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """Per-member holdout errors of every member's Gaussian mean.

    :param model: the ensemble
    :param x: standardised holdout inputs ``[H, in]``
    :param y: standardised holdout targets ``[H, D]``
    :param done: holdout termination flags ``[H]`` or None
    :return: normalised-target MSE ``[E]``, the early-stopping score ``[E]`` (the MSE, + the BCE with a
        termination head) and the next-state MSE in raw units ``[E]``
    """
    mean, _, logit = model._forward(x.unsqueeze(0).expand(model.n_members, -1, -1))  # [E, H, D]
    err = mean - y  # [E, H, D]
    mse = (err**2).mean(dim=(1, 2))  # [E]
    raw_state_mse = ((err * model.target_std)[..., : model.obs_dim] ** 2).mean(dim=(1, 2))  # [E]
    score = mse
    if logit is not None and done is not None:
        score = mse + F.binary_cross_entropy_with_logits(logit, done.expand_as(logit), reduction="none").mean(dim=1)
    return mse, score, raw_state_mse


class EarlyStopping:
    """Holdout early stopping per member, keeping each member's best weights.

    After every epoch, a member whose holdout score improved by more than 1% on its best keeps a snapshot
    of its weights (the linear layers; the shared log-variance bounds are not per member). Training stops
    after ``patience`` epochs without such an improvement of any member.

    :param model: the ensemble being fitted (snapshots are taken at construction)
    :param patience: epochs without an improvement before :attr:`should_stop`
    """

    def __init__(self, model: EnsembleDynamics, patience: int) -> None:
        self.patience = patience
        self.member_params = [p for layer in model.linear_layers for p in (layer.weight, layer.bias)]
        self.snapshots = [p.detach().clone() for p in self.member_params]
        self.best = th.full((model.n_members,), float("inf"), device=model.obs_mean.device)
        self.epochs_since_improvement = 0

    @th.no_grad()
    def update(self, score: th.Tensor) -> th.Tensor:
        """Record an epoch's scores; snapshot the members that improved.

        :param score: holdout score per member ``[E]`` (lower is better)
        :return: which members improved ``[E]`` (bool)
        """
        improved = score < self.best * 0.99  # relative improvement > 1%
        self.best = th.where(improved, score, self.best)
        for snap, p in zip(self.snapshots, self.member_params, strict=True):
            snap.copy_(th.where(improved.view(-1, 1, 1), p, snap))
        self.epochs_since_improvement = 0 if bool(improved.any()) else self.epochs_since_improvement + 1
        return improved

    @property
    def should_stop(self) -> bool:
        """``patience`` epochs in a row without an improvement of any member."""
        return self.epochs_since_improvement >= self.patience

    @th.no_grad()
    def restore_best(self) -> None:
        """Give every member back the weights of its best epoch."""
        for snap, p in zip(self.snapshots, self.member_params, strict=True):
            p.copy_(snap)


def select_elites(score: th.Tensor, n_elites: int) -> th.Tensor:
    """The ``n_elites`` members of lowest holdout score, in increasing index order.

    :param score: holdout score per member ``[E]``
    :param n_elites: number of elites
    :return: member indices ``[n_elites]`` (int64)
    """
    return th.sort(th.argsort(score)[:n_elites]).values


@th.no_grad()
def holdout_errors(model: EnsembleDynamics, data: Transitions, rows: th.Tensor) -> dict[str, float]:
    """Raw-space errors of the deterministic :meth:`EnsembleDynamics.step` (the elites' mean) on the transitions ``rows``.

    :param model: the fitted ensemble
    :param data: the transitions
    :param rows: the holdout rows
    :return: ``holdout_mse`` (next state), ``no_change_mse`` (the same for ``s' = s``), ``holdout_reward_mse``,
        and ``holdout_term_acc`` with a termination head
    """
    obs, next_obs = data.observations[rows], data.next_observations[rows]
    pred_obs, pred_rew, pred_term, _ = model.step(obs, data.actions[rows], deterministic=True)
    metrics = {
        "holdout_mse": float(((pred_obs - next_obs) ** 2).mean()),
        "no_change_mse": float(((obs - next_obs) ** 2).mean()),
        "holdout_reward_mse": float(((pred_rew - data.rewards[rows, 0]) ** 2).mean()),
    }
    done = data.done_rows(rows)
    if done is not None:
        metrics["holdout_term_acc"] = float(((pred_term > 0.5).float() == done).float().mean())
    return metrics


class DynamicsTrainer:
    """Fits an :class:`EnsembleDynamics` on transitions with holdout early stopping, then picks the elites.

    A random ``min(holdout_ratio * N, max_holdout)`` transitions are held out (:func:`holdout_split`);
    normalisation statistics come from the rest (:func:`split_statistics`). Every member trains on its own
    bootstrap resample of the training split (:class:`BootstrapBatches`), all members in one batched forward
    per Adam step. An *epoch* is one pass over the resample, capped at ``max_epoch_steps`` gradient steps (so
    that 1M transitions give epochs of 1000 steps, not 3,900); after every epoch each member's holdout score
    is measured (:func:`holdout_scores`) and :class:`EarlyStopping` keeps the best weights of every member and
    stops after ``patience`` epochs without an improvement of any member (or at ``max_epochs`` / ``max_steps``).
    Each member ends with its best weights; the ``n_elites`` best holdout members become the elites
    (:func:`select_elites`).

    Memory: the data are not copied (float32 tensors on the model's device are used as they are); the fit keeps
    index tensors (int32 split permutation and ``[E, N]`` bootstrap) and gathers and standardises each minibatch
    from the caller's tensors, which it never modifies. All randomness comes from torch's global RNG:
    ``th.manual_seed`` makes a fit reproducible. The Adam state lives in the trainer: a second :meth:`fit` of
    the same trainer continues from it.

    :param model: the ensemble to fit
    :param batch_size: minibatch size per member
    :param learning_rate: Adam learning rate
    :param holdout_ratio: fraction of the data held out for early stopping
    :param max_holdout: maximum holdout size
    :param max_epochs: stop after this many epochs (``None``: early stopping only)
    :param max_steps: stop after this many gradient steps in total (``None``: no limit)
    :param patience: epochs without a >1% improvement of any member before stopping
    :param max_epoch_steps: cap on the gradient steps of one epoch (``None``: a full pass)
    :param progress_bar: show a tqdm bar over epochs (total: the epoch limit; postfix: the holdout score), on a terminal
    :param logger: SB3 logger; ``dynamics/*`` values are recorded and dumped after every epoch (to stdout at
        ``verbose >= 2`` only)
    :param verbose: 1: a summary line at the end, 2: a line and the logger's table per epoch
    """

    def __init__(
        self,
        model: EnsembleDynamics,
        *,
        batch_size: int = 256,
        learning_rate: float = 1e-3,
        holdout_ratio: float = 0.2,
        max_holdout: int = 1000,
        max_epochs: int | None = None,
        max_steps: int | None = None,
        patience: int = 5,
        max_epoch_steps: int | None = 1000,
        progress_bar: bool = False,
        logger: Logger | None = None,
        verbose: int = 0,
    ) -> None:
        check_fit_kwargs(
            dict(
                batch_size=batch_size,
                learning_rate=learning_rate,
                holdout_ratio=holdout_ratio,
                max_holdout=max_holdout,
                max_epochs=max_epochs,
                max_steps=max_steps,
                patience=patience,
                max_epoch_steps=max_epoch_steps,
            ),
            name="",
        )
        self.model = model
        self.batch_size = batch_size
        self.holdout_ratio = holdout_ratio
        self.max_holdout = max_holdout
        self.max_epochs = max_epochs
        self.max_steps = max_steps
        self.patience = patience
        self.max_epoch_steps = max_epoch_steps
        self.progress_bar = progress_bar
        self.logger = logger
        self.verbose = verbose
        self.optimizer = th.optim.Adam(model.parameters(), lr=learning_rate)
        self._pbar: tqdm | None = None

    def fit(
        self,
        observations: th.Tensor | np.ndarray,
        actions: th.Tensor | np.ndarray,
        next_observations: th.Tensor | np.ndarray,
        rewards: th.Tensor | np.ndarray,
        dones: th.Tensor | np.ndarray | None = None,
    ) -> dict[str, float]:
        """Train the ensemble on transitions, with holdout early stopping, then pick the elites.

        ``fit`` makes the parameters trainable again (undoes :meth:`EnsembleDynamics.freeze`) and leaves the
        model in eval mode.

        :param observations: ``[N, obs_dim]``
        :param actions: ``[N, action_dim]``
        :param next_observations: ``[N, obs_dim]`` (the episode's own next observations)
        :param rewards: ``[N]``
        :param dones: ``[N]`` termination flags, true terminations only, not time-limit truncations
            (needed with ``learn_termination``, ignored otherwise)
        :return: ``holdout_mse`` (raw next-state MSE of the deterministic elite-mean prediction on the
            holdout), ``no_change_mse`` (same for ``s' = s``), ``holdout_reward_mse``, ``holdout_norm_mse``
            (elites' mean normalised-target MSE), ``holdout_term_acc`` (with a termination head),
            ``train_loss``, ``epochs``, ``steps``, ``fit_time`` (seconds)
        """
        start = time.perf_counter()
        model = self.model
        data = Transitions.from_arrays(model, observations, actions, next_observations, rewards, dones)
        split = holdout_split(len(data), self.holdout_ratio, self.max_holdout, device=data.observations.device)
        stats = split_statistics(data.observations, data.actions, data.next_observations, data.rewards, split.train)
        model.set_normalization(stats)
        x_hold, y_hold = data.standardized(split.holdout, stats)  # [H, in], [H, D]
        d_hold = data.done_rows(split.holdout)
        no_change_mse = float(((data.next_observations[split.holdout] - data.observations[split.holdout]) ** 2).mean())
        batches = BootstrapBatches(split.train, model.n_members, self.batch_size)

        model.requires_grad_(True)
        model.train()
        stopping = EarlyStopping(model, self.patience)
        self._open_progress(self._epoch_limit(batches.steps_per_pass))
        epoch, step, train_loss = 0, 0, float("nan")
        while self._within_budget(epoch, step):
            n_steps = self._epoch_steps(batches.steps_per_pass, step)
            train_loss = self.train_epoch(data, stats, batches, n_steps)
            epoch, step = epoch + 1, step + n_steps
            mse, score, raw_state_mse = holdout_scores(model, x_hold, y_hold, d_hold)  # [E]
            stopping.update(score)
            record = {
                "dynamics/train_loss": train_loss,
                "dynamics/holdout_mse": float(raw_state_mse.mean()),  # members' mean, raw next state
                "dynamics/no_change_mse": no_change_mse,
                "dynamics/holdout_norm_mse": float(mse.mean()),
                "dynamics/best_holdout_norm_mse": float(stopping.best.min()),
                "dynamics/epoch": epoch,
                "dynamics/steps": step,
            }
            self._report_epoch(record, stopping.epochs_since_improvement)
            if stopping.should_stop:
                break
        self._close_progress()
        self.optimizer.zero_grad(set_to_none=True)  # leave no stale gradients on the parameters

        # Best weights of every member, then the elites.
        stopping.restore_best()
        mse, score, _ = holdout_scores(model, x_hold, y_hold, d_hold)
        model.set_elites(select_elites(score, model.n_elites))
        model.eval()
        metrics = holdout_errors(model, data, split.holdout)
        metrics.update(
            holdout_norm_mse=float(mse[model.elites].mean()),
            train_loss=train_loss,
            epochs=float(epoch),
            steps=float(step),
            fit_time=time.perf_counter() - start,
        )
        self._report_fit(metrics)
        return metrics

    def train_epoch(self, data: Transitions, stats: NormalizationStats, batches: BootstrapBatches, n_steps: int) -> float:
        """``n_steps`` Adam steps of the ensemble's loss (:meth:`EnsembleDynamics._loss`), all members per step.

        :param data: the transitions
        :param stats: the normalisation statistics of the training split
        :param batches: the members' bootstrap minibatches
        :param n_steps: gradient steps
        :return: the mean training loss of these steps (NaN-free: 0 for no step)
        """
        loss_sum = th.zeros((), device=data.observations.device)
        for _ in range(n_steps):
            rows = batches.next_rows()  # [E, b]
            x, y = data.standardized(rows, stats)  # [E, b, in], [E, b, D]
            mean, logvar, logit = self.model._forward(x)  # [E, b, D]
            loss = self.model._loss(mean, logvar, logit, y, data.done_rows(rows))
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.optimizer.step()
            loss_sum += loss.detach()
        return float(loss_sum) / max(n_steps, 1)

    def _within_budget(self, epoch: int, step: int) -> bool:
        """Whether ``max_epochs`` and ``max_steps`` leave room for another epoch.

        :param epoch: epochs done
        :param step: gradient steps done
        :return: room for another epoch
        """
        return (self.max_epochs is None or epoch < self.max_epochs) and (self.max_steps is None or step < self.max_steps)

    def _epoch_steps(self, steps_per_pass: int, step: int) -> int:
        """Gradient steps of the next epoch: a pass, capped at ``max_epoch_steps`` and by what ``max_steps`` leaves.

        :param steps_per_pass: steps of one pass over the resample
        :param step: gradient steps done
        :return: steps of the next epoch
        """
        n_steps = steps_per_pass if self.max_epoch_steps is None else max(1, min(steps_per_pass, self.max_epoch_steps))
        return n_steps if self.max_steps is None else min(n_steps, self.max_steps - step)

    def _epoch_limit(self, steps_per_pass: int) -> int | None:
        """The most epochs ``max_epochs`` and ``max_steps`` allow (``None``: no limit but early stopping).

        :param steps_per_pass: steps of one pass over the resample
        :return: the epoch limit
        """
        limits = [] if self.max_epochs is None else [self.max_epochs]
        if self.max_steps is not None:
            limits.append(math.ceil(self.max_steps / self._epoch_steps(steps_per_pass, 0)))
        return min(limits) if limits else None

    def _open_progress(self, total: int | None) -> None:
        """Open the bar over epochs, with ``progress_bar``: the epoch limit as its total, hence an ETA; no bar (nor
        cursor codes) when stderr is not a terminal (``disable=None``).

        :param total: the epoch limit (``None``: none)
        """
        if self.progress_bar:
            from tqdm.auto import tqdm

            self._pbar = tqdm(total=total, desc="dynamics fit", unit="epoch", disable=None, leave=False)

    def _close_progress(self) -> None:
        """Close the tqdm bar, if any."""
        if self._pbar is not None:
            self._pbar.close()
            self._pbar = None

    def _report_epoch(self, record: dict[str, float], epochs_since_improvement: int) -> None:
        """Log, print and show one epoch's values.

        :param record: the ``dynamics/*`` values of the epoch
        :param epochs_since_improvement: epochs without an improvement of any member
        """
        if self.logger is not None:
            self._dump(record, step=int(record["dynamics/steps"]))
        if self.verbose >= 2:
            r = {key.removeprefix("dynamics/"): value for key, value in record.items()}
            print(
                f"dynamics epoch {r['epoch']} steps {r['steps']}: train loss {r['train_loss']:.4f}, "
                f"holdout next-state mse {r['holdout_mse']:.5f} (no change {r['no_change_mse']:.5f}), "
                f"normalised {r['holdout_norm_mse']:.5f} (best {r['best_holdout_norm_mse']:.5f}), "
                f"no improvement for {epochs_since_improvement}"
            )
        if self._pbar is not None:
            self._pbar.update(1)
            self._pbar.set_postfix(
                holdout=f"{record['dynamics/holdout_norm_mse']:.4f}",
                best=f"{record['dynamics/best_holdout_norm_mse']:.4f}",
                refresh=False,
            )

    def _dump(self, record: dict[str, float], step: int) -> None:
        """Record and dump values to the logger: every output format, but stdout only at ``verbose >= 2`` (a table
        per epoch buries the rest; the bar and the summary line say what matters).

        :param record: the values
        :param step: the logger's step
        """
        assert self.logger is not None
        exclude = None if self.verbose >= 2 else ("stdout", "log")
        for key, value in record.items():
            self.logger.record(key, value, exclude=exclude)
        with warnings.catch_warnings():  # with stdout excluded, its format has nothing to write and says so
            warnings.filterwarnings("ignore", message="Tried to write empty key-value dict")
            self.logger.dump(step=step)

    def _report_fit(self, metrics: dict[str, float]) -> None:
        """Log and print the fit's final metrics.

        :param metrics: what :meth:`fit` returns
        """
        step = int(metrics["steps"])
        if self.logger is not None:
            self._dump({f"dynamics/{key}": value for key, value in metrics.items()}, step=step)
        if self.verbose >= 1:
            print(
                f"dynamics fit: {int(metrics['epochs'])} epochs, {step} steps, {metrics['fit_time']:.1f} s; holdout "
                f"next-state mse {metrics['holdout_mse']:.5f} vs no-change {metrics['no_change_mse']:.5f}, "
                f"reward mse {metrics['holdout_reward_mse']:.5f}, elites {self.model.elites.tolist()}"
            )
