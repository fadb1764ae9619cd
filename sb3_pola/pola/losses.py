"""The losses of POLA as pure functions: the look-ahead objective (eq. 3/4) and EDAC's ensemble similarity."""

from __future__ import annotations

import torch as th


def lookahead_weights(gamma_powers: th.Tensor, normalization: str) -> th.Tensor:
    """``[T+1]`` weights of the look-ahead terms: ``gamma^i`` (eq. 3), or divided by their sum (``"weights"``)."""
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
    if lcb_coef is None:
        q_top_k = q.topk(top_k, dim=0, largest=False).values.mean(dim=0)  # [T+1, B]: mean of the K smallest members
    else:
        q_top_k = q.mean(dim=0) - lcb_coef * q.std(dim=0)  # [T+1, B]
    per_step = (alive * q_top_k).mean(dim=1)  # [T+1]
    # scale-free Q term (Diffusion-QL): divide by the detached mean |Q| at the current states
    q_scale = q_top_k[0].abs().mean().detach().clamp_min(max(q_scale_floor, 1e-6))
    # eq. 3 / 4: L_q = -sum_{i=0..T} gamma^i (1/K) topK_j Q_j(s_{t+i}, a_{t+i}), terms after a terminal state masked
    return -(lookahead_weights(gamma_powers, normalization) * per_step).sum() / q_scale, per_step
