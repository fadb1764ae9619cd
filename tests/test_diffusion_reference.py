"""Eq. 1, 5 against float64 NumPy references written from the paper, not from the code under test.

The betas of every schedule are literals (computed once from the published formulas); the posterior coefficients
of every step and a full reverse chain (a toy noise predictor, given noise) are recomputed here in float64.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

from sb3_pola.common.diffusion import NoiseSchedule
from sb3_pola.pola.policies import DiffusionActor

# n = 5. vp: 1 - exp(-0.1/5 - 0.5 (10 - 0.1)(2t - 1)/25), t = 1..5 (Diffusion-QL); linear: DDPM's 1e-4 .. 2e-2;
# cosine: Nichol & Dhariwal with s = 0.008, clipped to 0.999
BETAS = {
    "vp": [0.195874558333, 0.458818193385, 0.635781020428, 0.754878187961, 0.835031379177],
    "linear": [0.0001, 0.005075, 0.01005, 0.015025, 0.02],
    "cosine": [0.1012940794, 0.279543845984, 0.473635353449, 0.724052369108, 0.999],
}


def posterior(betas: list[float]) -> dict[str, np.ndarray]:
    """Eq. 1's coefficients per step ``t = 0 .. n-1`` in float64: ``x_{t-1} = c1 x_0 + c2 x_t + sigma_t z``."""
    beta = np.array(betas, dtype=np.float64)
    alpha = 1.0 - beta
    abar = np.cumprod(alpha)
    abar_prev = np.concatenate(([1.0], abar[:-1]))
    sigma = np.sqrt(beta * (1.0 - abar_prev) / (1.0 - abar))
    sigma[0] = 0.0  # no noise at the last reverse step
    return {
        "abar": abar,
        "recip": np.sqrt(1.0 / abar),
        "recipm1": np.sqrt(1.0 / abar - 1.0),
        "c1": beta * np.sqrt(abar_prev) / (1.0 - abar),
        "c2": (1.0 - abar_prev) * np.sqrt(alpha) / (1.0 - abar),
        "sigma": sigma,
    }


def toy_eps(x: np.ndarray, t: int, features: np.ndarray) -> np.ndarray:
    """A noise predictor simple enough to write twice: linear in the action, the step and the state."""
    return 0.7 * x - 0.2 * t + 0.5 * features[:, :1]


def reference_chain(betas: list[float], features: np.ndarray, noise: np.ndarray | None) -> np.ndarray:
    """Eq. 5 in float64 from ``a_T`` (``noise[-1]``, or 0 for the noise-free chain), ``x_0`` clipped to [-1, 1]."""
    c = posterior(betas)
    x = np.zeros((features.shape[0], 2)) if noise is None else noise[-1]
    for t in reversed(range(len(betas))):
        x0 = np.clip(c["recip"][t] * x - c["recipm1"][t] * toy_eps(x, t, features), -1.0, 1.0)
        x = c["c1"][t] * x0 + c["c2"][t] * x
        if noise is not None and t > 0:
            x = x + c["sigma"][t] * noise[t]
    return np.clip(x, -1.0, 1.0)


@pytest.mark.parametrize("name", sorted(BETAS))
def test_betas_are_the_published_ones(name: str) -> None:
    schedule = NoiseSchedule(5, name)
    np.testing.assert_allclose(schedule.betas.double().numpy(), BETAS[name], rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("name", sorted(BETAS))
def test_posterior_coefficients_of_every_step(name: str) -> None:
    schedule = NoiseSchedule(5, name)
    want = posterior(BETAS[name])
    got = {
        "abar": schedule.alphas_cumprod,
        "recip": schedule.sqrt_recip_alphas_cumprod,
        "recipm1": schedule.sqrt_recipm1_alphas_cumprod,
        "c1": schedule.posterior_mean_coef1,
        "c2": schedule.posterior_mean_coef2,
        "sigma": schedule.noise_std,
    }
    for key, value in got.items():
        np.testing.assert_allclose(value.double().numpy(), want[key], rtol=1e-5, atol=1e-7, err_msg=key)
    # the float constants of the fast chains and of the export, step by step
    for t, (recip, recipm1, c1, c2, sigma) in enumerate(schedule.step_constants):
        np.testing.assert_allclose(
            [recip, recipm1, c1, c2, sigma],
            [want["recip"][t], want["recipm1"][t], want["c1"][t], want["c2"][t], want["sigma"][t]],
            rtol=1e-5,
            atol=1e-7,
            err_msg=f"step {t}",
        )


@pytest.mark.parametrize("name", sorted(BETAS))
@pytest.mark.parametrize("deterministic", [False, True])
def test_full_chain_with_a_toy_noise_predictor(name: str, deterministic: bool) -> None:
    """``DiffusionActor.sample`` with its network replaced by :func:`toy_eps` and the noise it draws given here."""
    actor = DiffusionActor(features_dim=3, action_dim=2, net_arch=[8], n_diffusion_steps=5, beta_schedule=name)

    def predict_noise(x_t: th.Tensor, t: th.Tensor, features: th.Tensor) -> th.Tensor:
        assert bool((t == t[0]).all())
        return th.as_tensor(toy_eps(x_t.double().numpy(), int(t[0]), features.double().numpy()), dtype=x_t.dtype)

    actor.predict_noise = predict_noise  # type: ignore[method-assign]
    features = th.linspace(-1.5, 1.5, 12).reshape(4, 3)
    noise = None if deterministic else th.randn((6, 4, 2), generator=th.Generator().manual_seed(5))  # a_T last
    got = actor.sample(features, generator=th.Generator().manual_seed(5), deterministic=deterministic)
    want = reference_chain(BETAS[name], features.double().numpy(), None if noise is None else noise.double().numpy())
    np.testing.assert_allclose(got.double().numpy(), want, rtol=1e-5, atol=1e-6)
    assert not deterministic or np.abs(want).max() > 0.05  # the chain moves away from a_T = 0
