"""DDPM noise schedule for the diffusion actor (paper eq. 1, 2, 5, 6).

The schedule is a small module whose coefficients are buffers (like diffusers' ``DDPMScheduler``),
so it moves with ``.to(device)`` and is rebuilt, not loaded, from its two hyperparameters.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch as th
from torch import nn


def vp_beta_schedule(n_steps: int, beta_min: float = 0.1, beta_max: float = 10.0) -> th.Tensor:
    """Variance-preserving schedule of Diffusion-QL: ``alpha_t = exp(-b_min/T - (b_max-b_min)(2t-1)/(2T^2))``."""
    t = th.arange(1, n_steps + 1, dtype=th.float64)
    alpha = th.exp(-beta_min / n_steps - 0.5 * (beta_max - beta_min) * (2 * t - 1) / n_steps**2)
    return 1.0 - alpha


def linear_beta_schedule(n_steps: int, beta_start: float = 1e-4, beta_end: float = 2e-2) -> th.Tensor:
    """Linear betas of the original DDPM."""
    return th.linspace(beta_start, beta_end, n_steps, dtype=th.float64)


def cosine_beta_schedule(n_steps: int, s: float = 0.008) -> th.Tensor:
    """Cosine schedule (Nichol & Dhariwal, 2021), betas clipped to [0, 0.999]."""
    x = th.linspace(0, n_steps, n_steps + 1, dtype=th.float64)
    alphas_cumprod = th.cos(((x / n_steps) + s) / (1 + s) * math.pi * 0.5) ** 2
    alphas_cumprod = alphas_cumprod / alphas_cumprod[0]
    return th.clip(1 - alphas_cumprod[1:] / alphas_cumprod[:-1], 0.0, 0.999)


BETA_SCHEDULES: dict[str, Callable[[int], th.Tensor]] = {
    "vp": vp_beta_schedule,
    "linear": linear_beta_schedule,
    "cosine": cosine_beta_schedule,
}


PREDICTION_TYPES = ("epsilon", "sample")


class NoiseSchedule(nn.Module):
    """DDPM forward (``add_noise``) and reverse (``step``) process over ``n_steps`` diffusion steps.

    Steps are indexed ``t = 0 .. n_steps - 1`` (the paper's ``1 .. T``). Coefficients are
    non-persistent buffers: derived from ``(n_steps, beta_schedule)``, never stored in checkpoints.

    :param n_steps: number of diffusion steps (Diffusion-QL and POLA: 5)
    :param beta_schedule: ``"vp"``, ``"linear"`` or ``"cosine"``
    :param prediction_type: what the network predicts: ``"epsilon"``, the noise (eq. 2 / 6, DDPM), or
        ``"sample"``, the clean action ``x_0`` (Diffuser's and Diffusion-QL's ``predict_epsilon=False``)
    """

    def __init__(self, n_steps: int = 5, beta_schedule: str = "vp", prediction_type: str = "epsilon") -> None:
        super().__init__()
        if beta_schedule not in BETA_SCHEDULES:
            raise ValueError(f"Unknown beta_schedule {beta_schedule!r}; choose one of {sorted(BETA_SCHEDULES)}")
        if n_steps < 1:
            raise ValueError(f"n_steps must be >= 1, got {n_steps}")
        if prediction_type not in PREDICTION_TYPES:
            raise ValueError(f"Unknown prediction_type {prediction_type!r}; choose one of {PREDICTION_TYPES}")
        self.n_steps = n_steps
        self.beta_schedule = beta_schedule
        self.prediction_type = prediction_type

        betas = BETA_SCHEDULES[beta_schedule](n_steps)  # float64 for exact coefficients, stored as float32
        alphas = 1.0 - betas
        alphas_cumprod = th.cumprod(alphas, dim=0)
        alphas_cumprod_prev = th.cat([th.ones(1, dtype=th.float64), alphas_cumprod[:-1]])
        # eq. 1: posterior q(x_{t-1} | x_t, x_0) variance beta~_t
        posterior_variance = betas * (1.0 - alphas_cumprod_prev) / (1.0 - alphas_cumprod)
        coefficients = {
            "betas": betas,
            "alphas_cumprod": alphas_cumprod,
            "alphas_cumprod_prev": alphas_cumprod_prev,
            "sqrt_alphas_cumprod": alphas_cumprod.sqrt(),
            "sqrt_one_minus_alphas_cumprod": (1.0 - alphas_cumprod).sqrt(),
            "sqrt_recip_alphas_cumprod": (1.0 / alphas_cumprod).sqrt(),
            "sqrt_recipm1_alphas_cumprod": (1.0 / alphas_cumprod - 1).sqrt(),
            "posterior_variance": posterior_variance,
            # beta~_0 = 0: its log is clipped; no noise is ever added at t = 0 (the last reverse step)
            "posterior_log_variance_clipped": th.log(posterior_variance.clamp_min(1e-20)),
            "posterior_mean_coef1": betas * alphas_cumprod_prev.sqrt() / (1.0 - alphas_cumprod),
            "posterior_mean_coef2": (1.0 - alphas_cumprod_prev) * alphas.sqrt() / (1.0 - alphas_cumprod),
        }
        # std of the noise added at each reverse step; zero at the last step (t = 0)
        noise_std = th.exp(0.5 * coefficients["posterior_log_variance_clipped"])
        noise_std[0] = 0.0
        coefficients["noise_std"] = noise_std
        for name, value in coefficients.items():
            self.register_buffer(name, value.float(), persistent=False)
        # per step (r_t, m_t, posterior mean coefficients c1, c2, sigma_t) as Python floats, for the fast chains
        # (sb3_pola.pola.fast_sampling, export): constants of a compiled graph. The clean-action estimate is
        # x_0 = r_t x_t - m_t out: (sqrt(1/abar_t), sqrt(1/abar_t - 1)) when out is the noise, (0, -1) when out is x_0
        sample = prediction_type == "sample"
        self.step_constants: list[tuple[float, float, float, float, float]] = [
            (
                0.0 if sample else float(self.sqrt_recip_alphas_cumprod[t]),
                -1.0 if sample else float(self.sqrt_recipm1_alphas_cumprod[t]),
                float(self.posterior_mean_coef1[t]),
                float(self.posterior_mean_coef2[t]),
                float(self.noise_std[t]),
            )
            for t in range(n_steps)
        ]
        # c1 >= 0 lets the fast no-grad chain fold c1 into the clip: c1 clip(z, -1, 1) = clip(c1 z, -c1, c1)
        assert all(c[2] >= 0.0 for c in self.step_constants)

    # Buffers declared for type checkers
    betas: th.Tensor
    alphas_cumprod: th.Tensor
    alphas_cumprod_prev: th.Tensor
    sqrt_alphas_cumprod: th.Tensor
    sqrt_one_minus_alphas_cumprod: th.Tensor
    sqrt_recip_alphas_cumprod: th.Tensor
    sqrt_recipm1_alphas_cumprod: th.Tensor
    posterior_variance: th.Tensor
    posterior_log_variance_clipped: th.Tensor
    posterior_mean_coef1: th.Tensor
    posterior_mean_coef2: th.Tensor
    noise_std: th.Tensor

    @staticmethod
    def _at(coef: th.Tensor, t: th.Tensor | int, ndim: int) -> th.Tensor:
        """``coef[t]`` shaped to broadcast against a ``[B, ...]`` tensor of ``ndim`` dims."""
        if isinstance(t, int):
            return coef[t]
        return coef[t].reshape(-1, *([1] * (ndim - 1)))

    def add_noise(self, x0: th.Tensor, noise: th.Tensor, t: th.Tensor | int) -> th.Tensor:
        """Forward process ``x_t = sqrt(abar_t) x_0 + sqrt(1 - abar_t) eps`` (the argument of eq. 2 / 6)."""
        return (
            self._at(self.sqrt_alphas_cumprod, t, x0.ndim) * x0
            + self._at(self.sqrt_one_minus_alphas_cumprod, t, x0.ndim) * noise
        )

    def predict_start_from_noise(self, x_t: th.Tensor, t: th.Tensor | int, noise: th.Tensor) -> th.Tensor:
        """Invert the forward process: ``x_0 = x_t / sqrt(abar_t) - sqrt(1/abar_t - 1) eps``."""
        return (
            self._at(self.sqrt_recip_alphas_cumprod, t, x_t.ndim) * x_t
            - self._at(self.sqrt_recipm1_alphas_cumprod, t, x_t.ndim) * noise
        )

    def q_posterior(self, x0: th.Tensor, x_t: th.Tensor, t: th.Tensor | int) -> tuple[th.Tensor, th.Tensor]:
        """Mean and log-variance of ``q(x_{t-1} | x_t, x_0)`` (eq. 1)."""
        mean = self._at(self.posterior_mean_coef1, t, x_t.ndim) * x0 + self._at(self.posterior_mean_coef2, t, x_t.ndim) * x_t
        return mean, self._at(self.posterior_log_variance_clipped, t, x_t.ndim)

    def step(
        self,
        model_output: th.Tensor,
        t: int,
        x_t: th.Tensor,
        noise: th.Tensor | None,
        clip: float | None = 1.0,
    ) -> th.Tensor:
        """One reverse step ``x_t -> x_{t-1}`` (eq. 5) from the network's output (the noise, or ``x_0``).

        The predicted ``x_0`` is clipped to ``[-clip, clip]`` (the action bounds) before the
        posterior mean is formed, as in Diffusion-QL. ``noise=None`` gives the posterior mean.
        """
        x0 = model_output if self.prediction_type == "sample" else self.predict_start_from_noise(x_t, t, model_output)
        if clip is not None:
            x0 = x0.clamp(-clip, clip)
        mean, _ = self.q_posterior(x0, x_t, t)
        if noise is None or t == 0:
            return mean
        return mean + self.noise_std[t] * noise

    def extra_repr(self) -> str:
        return f"n_steps={self.n_steps}, beta_schedule={self.beta_schedule!r}, prediction_type={self.prediction_type!r}"
