"""One term of a loss at its own learning rate, inside one Adam (issue #23).

Adam on ``L = L_a + L_b`` moves a parameter by ``lr * m_hat / (sqrt(v_hat) + eps)``, where ``m`` is the first moment of
``g_a + g_b`` and ``v`` the second. ``m`` is linear in the gradient, ``m = m_a + m_b``, so giving the term ``a`` its
own rate ``lr_a`` is the step ``(lr_a * m_hat_a + lr * m_hat_b) / (sqrt(v_hat) + eps)``: the same denominator (the summed
gradient's scale), each term's direction at its rate. It is Adam's step plus ``(lr_a - lr) * m_hat_a / (sqrt(v_hat) +
eps)``, so the optimizer itself stays ``torch.optim.Adam`` (or ``AdamW``), its saved state too, and with
``lr_a = lr`` the step is Adam's to the bit. Two optimizers, one per term, would each rescale their term by its own
``v``: the terms' balance (POLA's ``eta``) would be lost.
"""

from __future__ import annotations

import math

import torch as th

TERM_MOMENT = "term_exp_avg"  # the term's first moment, kept in the optimizer's per-parameter state (saved with it)


def check_term_rate_optimizer(optimizer: th.optim.Optimizer) -> None:
    """The term's step reads Adam's second moment: only Adam and AdamW without ``amsgrad`` or ``maximize`` have it."""
    if type(optimizer) not in (th.optim.Adam, th.optim.AdamW):
        raise ValueError(f"a term's own learning rate needs torch.optim.Adam or AdamW, not {type(optimizer).__name__}")
    for group in optimizer.param_groups:
        if group.get("amsgrad") or group.get("maximize"):
            raise ValueError("a term's own learning rate needs Adam without amsgrad or maximize")


@th.no_grad()
def term_rate_step(optimizer: th.optim.Optimizer, term_grads: list[th.Tensor | None], term_lr: float) -> None:
    """After ``optimizer.step()`` on the summed gradient, move the term whose gradient is ``term_grads`` (one per
    parameter of the optimizer's groups, in order) from the group's rate to ``term_lr``.

    Every call updates the term's first moment, so call it every step, whatever the rates.
    """
    grads = iter(term_grads)
    for group in optimizer.param_groups:
        beta1, beta2 = group["betas"]
        for param in group["params"]:
            grad = next(grads)
            state = optimizer.state.get(param)
            if grad is None or not state:  # no gradient this step: Adam did not step it either
                continue
            moment = state.get(TERM_MOMENT)
            if moment is None:
                moment = state[TERM_MOMENT] = th.zeros_like(param)
            moment.lerp_(grad, 1.0 - beta1)
            delta = term_lr - float(group["lr"])
            if delta == 0.0:
                continue
            step = float(state["step"])
            # Adam's own denominator: sqrt(v) / sqrt(1 - beta2^t) + eps
            denom = (state["exp_avg_sq"].sqrt() / math.sqrt(1.0 - beta2**step)).add_(group["eps"])
            param.addcdiv_(moment, denom, value=-delta / (1.0 - beta1**step))


__all__ = ["TERM_MOMENT", "check_term_rate_optimizer", "term_rate_step"]
