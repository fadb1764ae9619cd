"""sb3_pola.common.term_rates: one term of a loss at its own rate inside one Adam (#23)."""

from __future__ import annotations

import pytest
import torch as th

from sb3_pola.common.term_rates import TERM_MOMENT, check_term_rate_optimizer, term_rate_step


def _steps(term_lr: float | None, n_steps: int = 6, lr: float = 1e-2, weight_decay: float = 0.0):
    """Adam on ``L = L_a + L_b`` with random gradients; ``term_lr``: ``L_a``'s own rate (``None``: plain Adam)."""
    gen = th.Generator().manual_seed(0)
    params = [th.randn(4, 3, generator=gen).requires_grad_(), th.randn(5, generator=gen).requires_grad_()]
    optimizer = th.optim.Adam(params, lr=lr, eps=1e-8, weight_decay=weight_decay)
    history = []
    for _ in range(n_steps):
        grads_a = [th.randn(p.shape, generator=gen) for p in params]
        grads_b = [3.0 * th.randn(p.shape, generator=gen) for p in params]
        for p, ga, gb in zip(params, grads_a, grads_b, strict=True):
            p.grad = ga + gb
        optimizer.step()
        if term_lr is not None:
            term_rate_step(optimizer, grads_a, term_lr)
        history.append((grads_a, grads_b))
    return [p.detach().clone() for p in params], history, optimizer


def test_the_same_rate_is_adam_to_the_bit():
    plain, _, _ = _steps(None)
    same, _, optimizer = _steps(1e-2)
    for got, want in zip(same, plain, strict=True):
        assert th.equal(got, want)
    assert all(TERM_MOMENT in state for state in optimizer.state.values())  # the moment is kept all the same


def test_each_term_moves_at_its_own_rate_over_one_second_moment():
    """The step is ``(lr_a m_hat_a + lr m_hat_b) / (sqrt(v_hat) + eps)``, ``v`` the summed gradient's (written out)."""
    lr, lr_a, beta1, beta2, eps = 1e-2, 3e-3, 0.9, 0.999, 1e-8
    got, history, _ = _steps(lr_a, lr=lr)
    gen = th.Generator().manual_seed(0)
    want = [th.randn(4, 3, generator=gen), th.randn(5, generator=gen)]
    m_a = [th.zeros_like(p) for p in want]
    m_b = [th.zeros_like(p) for p in want]
    v = [th.zeros_like(p) for p in want]
    for t, (grads_a, grads_b) in enumerate(history, start=1):
        for i, (ga, gb) in enumerate(zip(grads_a, grads_b, strict=True)):
            m_a[i] = beta1 * m_a[i] + (1 - beta1) * ga
            m_b[i] = beta1 * m_b[i] + (1 - beta1) * gb
            v[i] = beta2 * v[i] + (1 - beta2) * (ga + gb) ** 2
            denom = (v[i] / (1 - beta2**t)).sqrt() + eps
            want[i] = want[i] - (lr_a * m_a[i] + lr * m_b[i]) / (1 - beta1**t) / denom
    for g, w in zip(got, want, strict=True):
        th.testing.assert_close(g, w, rtol=1e-5, atol=1e-6)
    # and it is not Adam at the one rate
    plain, _, _ = _steps(None, lr=lr)
    assert not th.allclose(got[0], plain[0], atol=1e-4)


def test_one_term_alone_is_adam_at_its_rate():
    gen = th.Generator().manual_seed(1)
    grads = [[th.randn(6, generator=gen)] for _ in range(5)]
    moved = []
    for rate, term in ((1e-2, 3e-3), (3e-3, None)):
        param = th.ones(6, requires_grad=True)
        optimizer = th.optim.Adam([param], lr=rate)
        for g in grads:
            param.grad = g[0].clone()
            optimizer.step()
            if term is not None:
                term_rate_step(optimizer, g, term)
        moved.append(param.detach())
    th.testing.assert_close(moved[0], moved[1])


def test_only_adam_without_amsgrad_or_maximize():
    param = th.zeros(2, requires_grad=True)
    check_term_rate_optimizer(th.optim.AdamW([param]))
    for optimizer in (th.optim.SGD([param], lr=0.1), th.optim.Adam([param], amsgrad=True)):
        with pytest.raises(ValueError, match="Adam"):
            check_term_rate_optimizer(optimizer)
