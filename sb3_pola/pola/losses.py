"""The losses of POLA as pure functions: the look-ahead objective (eq. 3/4) and EDAC's ensemble similarity."""

from __future__ import annotations

import torch as th


def lookahead_weights(gamma_powers: th.Tensor, normalization: str) -> th.Tensor:
    """``[T+1]`` weights of the look-ahead terms: ``gamma^i`` (eq. 3), or divided by their sum (``"weights"``).

    ``gamma_powers`` may carry ``lookahead_weight``'s factor on the terms ``i >= 1`` (``POLA._lookahead_powers``)."""
    return gamma_powers / gamma_powers.sum() if normalization == "weights" else gamma_powers


def value_lower_bound(rewards: th.Tensor, gamma: float) -> float:
    """The lowest value any policy can have on rewards no lower than the data's smallest ``r_min``.

    ``Q(s, a) = r + gamma r' + ...`` collects at least one reward, so ``Q >= r_min`` when ``r_min >= 0`` (an episode
    may end after it), and ``Q >= r_min / (1 - gamma)`` when ``r_min < 0`` (it may not end); ``-inf`` for
    ``r_min < 0`` with ``gamma = 1``.
    """
    r_min = float(rewards.min())
    if r_min >= 0:
        return r_min
    return r_min / (1.0 - gamma) if gamma < 1 else float("-inf")


def ensemble_similarity(q_action_grads: th.Tensor) -> th.Tensor:
    """EDAC's ensemble similarity (An et al., 2021, eq. 8): ``sum_{i != j} <g_i, g_j> / (N - 1)``, batch mean.

    ``g_i`` is member ``i``'s action gradient ``grad_a Q_i(s, a)`` at the dataset's ``(s, a)``, scaled to unit length.
    Penalising it makes the members' gradients point in different directions, so their Q-values part ways as
    the action leaves the data and the ensemble's minimum becomes pessimistic there.

    :param q_action_grads: ``[N, B, A]`` action gradients of the ``N`` members
    :return: the similarity, a scalar in ``[-N / (N - 1), N]`` (``N``: all members alike)
    """
    n_members = q_action_grads.shape[0]
    # g / sqrt(|g|^2 + eps): unit length, smooth and bounded at g = 0
    unit = q_action_grads * (q_action_grads.pow(2).sum(dim=-1, keepdim=True) + 1e-12).rsqrt()  # [N, B, A]
    # sum_{i != j} <u_i, u_j> = |sum_i u_i|^2 - sum_i |u_i|^2, without the [B, N, N] Gram matrix
    pairs = unit.sum(dim=0).pow(2).sum(dim=-1) - unit.pow(2).sum(dim=(0, 2))  # [B]
    return pairs.mean() / (n_members - 1)


def lookahead_q_objective(
    q: th.Tensor,
    alive: th.Tensor,
    gamma_powers: th.Tensor,
    top_k: int,
    normalization: str = "first",
    q_scale_floor: float = 0.0,
    lcb_coef: float | None = None,
) -> tuple[th.Tensor, th.Tensor]:
    """``L_q`` of eq. 4 (eq. 3 with the ensemble's top-K) from the ensemble's Q-values along the look-ahead.

    :param q: ``[N, T+1, B]`` Q-values of every member at ``(s_{t+i}, a_{t+i})``
    :param alive: ``[T+1, B]`` 1 while no earlier or current look-ahead state is terminal, else 0
    :param gamma_powers: ``[T+1]`` weights ``gamma^i`` (eq. 3)
    :param top_k: number ``K`` of smallest members averaged
    :param normalization: ``"first"``: eq. 3/4 as written, the weights ``gamma^i`` summed, so the Q term
        weighs ``sum_i gamma^i`` (about ``T + 1``) times its ``T = 0`` weight; ``"weights"``: the weights
        divided by their sum, so ``eta`` means the same for every ``T``
    :param q_scale_floor: lower bound of the divisor ``mean |Q|`` (``0``: Diffusion-QL's plain batch mean)
    :param lcb_coef: ``k`` of a lower confidence bound ``mean_j Q_j - k std_j Q_j`` over the members in place of
        the top-K mean (SAC-N / DAC): pessimism that grows with the members' disagreement; ``None``: top-K (eq. 4)
    :return: the loss and the ``[T+1]`` pessimistic Q per step (masked)
    """
    q_top_k = pessimistic_q(q, top_k, lcb_coef)  # [T+1, B]
    per_step = (alive * q_top_k).mean(dim=1)  # [T+1]
    # eq. 3 / 4: L_q = -sum_{i=0..T} gamma^i (1/K) topK_j Q_j(s_{t+i}, a_{t+i}), terms after a terminal state masked
    weighted = (lookahead_weights(gamma_powers, normalization) * per_step).sum()
    return -weighted / _q_scale(q_top_k, q_scale_floor), per_step


def pessimistic_q(q: th.Tensor, top_k: int, lcb_coef: float | None = None) -> th.Tensor:
    """``[T+1, B]`` pessimistic value over the ensemble's ``[N, T+1, B]``: the mean of the ``top_k`` smallest
    members (eq. 4), or ``mean - lcb_coef * std`` over the members."""
    if lcb_coef is None:
        return q.topk(top_k, dim=0, largest=False).values.mean(dim=0)
    return q.mean(dim=0) - lcb_coef * q.std(dim=0)


def advantage_weights(advantages: th.Tensor, temperature: th.Tensor | float, max_weight: float) -> th.Tensor:
    """``[B]`` weights of the imitation term over a batch's ``[B]`` advantages ``Q(s, a) - Q(s, pi(s))``: AWR's
    ``exp(temperature A)`` with ``A`` in units of the batch's standard deviation (scale-free: the same temperature on
    dense and sparse rewards), normalised to mean 1 over the batch (``B softmax``) so that ``L_d`` keeps its scale
    against ``L_q``, then clipped at ``max_weight``. Temperature 0: all 1 (plain behaviour cloning)."""
    scaled = advantages / advantages.std().clamp_min(1e-6)
    return (advantages.shape[0] * th.softmax(temperature * scaled, dim=0)).clamp(max=max_weight)


def _q_scale(q_top_k: th.Tensor, q_scale_floor: float) -> th.Tensor:
    """Scale-free Q term (Diffusion-QL): the detached mean ``|Q|`` at the current states, no lower than the floor."""
    return q_top_k[0].abs().mean().detach().clamp_min(max(q_scale_floor, 1e-6))


def value_expansion_objective(
    q: th.Tensor,
    rewards: th.Tensor,
    alive: th.Tensor,
    gamma_powers: th.Tensor,
    top_k: int,
    normalization: str = "first",
    q_scale_floor: float = 0.0,
    lcb_coef: float | None = None,
    expansion_weight: float = 1.0,
) -> tuple[th.Tensor, th.Tensor]:
    """``L_q`` with the look-ahead judged by the model's rewards: value expansions (MVE, Feinberg et al., 2018).

    ``V_h = sum_{i<h} gamma^i r_i + gamma^h Q(s_{t+h}, a_{t+h})`` for ``h = 0..T``: each is an estimate of the
    current ``Q(s_t, a_t)``, ``V_0`` being eq. 4's first term. Eq. 3 asks the critic at every predicted state;
    here the steps before the last are judged by the predicted reward, so the critic, which never trained at a
    model state, is asked once per expansion and discounted by ``gamma^h``. Every ``V_h`` is on ``Q(s_t, a_t)``'s
    scale: the ``T + 1`` expansions are summed (``"first"``, the Q term weighing ``T + 1`` times its ``T = 0``
    weight, as eq. 3's ``sum_i gamma^i`` does) or averaged (``"weights"``).

    :param q: ``[N, T+1, B]`` Q-values of every member at ``(s_{t+i}, a_{t+i})``
    :param rewards: ``[T, B]`` the model's rewards of ``(s_{t+i}, a_{t+i})``, ``i < T``, in the critic's units
    :param alive: ``[T+1, B]`` 1 while no earlier or current look-ahead state is terminal, else 0
    :param gamma_powers: ``[T+1]`` ``gamma^i``
    :param top_k: number ``K`` of smallest members averaged
    :param normalization: ``"first"`` (sum) or ``"weights"`` (mean) of the expansions
    :param q_scale_floor: lower bound of the divisor ``mean |Q|`` at the current states
    :param lcb_coef: lower confidence bound in place of the top-K mean (:func:`pessimistic_q`)
    :param expansion_weight: weight of each expansion ``V_h``, ``h >= 1``, against ``V_0``'s 1 (``lookahead_weight``)
    :return: the loss and the ``[T+1]`` batch means of ``V_h``
    """
    q_top_k = pessimistic_q(q, top_k, lcb_coef)  # [T+1, B]
    discounted = gamma_powers[:-1, None] * alive[:-1] * rewards  # [T, B]: r_i counts while s_{t+i} is alive
    reward_sums = th.cat([q_top_k.new_zeros(1, q_top_k.shape[1]), discounted.cumsum(dim=0)])  # [T+1, B]: sum_{i<h}
    values = reward_sums + gamma_powers[:, None] * alive * q_top_k  # [T+1, B]: V_h
    per_step = values.mean(dim=1)  # [T+1]
    weights = th.full_like(per_step, expansion_weight)
    weights[0] = 1.0
    total = (lookahead_weights(weights, normalization) * per_step).sum()  # summed ("first") or averaged
    return -total / _q_scale(q_top_k, q_scale_floor), per_step
