import math

import pytest
import torch as th

from sb3_pola.common.diffusion import NoiseSchedule


def test_vp_schedule_matches_diffusion_ql():
    schedule = NoiseSchedule(5, "vp")
    expected = th.tensor([0.196, 0.459, 0.636, 0.755, 0.835])
    assert th.allclose(schedule.betas, expected, atol=1e-3)
    # closed form: alpha_t = exp(-b_min/T - 0.5 (b_max - b_min)(2t - 1)/T^2)
    t = 3
    alpha = math.exp(-0.1 / 5 - 0.5 * 9.9 * (2 * t - 1) / 25)
    assert schedule.betas[t - 1].item() == pytest.approx(1 - alpha, rel=1e-5)


def test_linear_and_cosine_schedules():
    linear = NoiseSchedule(5, "linear")
    assert linear.betas[0].item() == pytest.approx(1e-4) and linear.betas[-1].item() == pytest.approx(2e-2)
    cosine = NoiseSchedule(10, "cosine")
    assert (cosine.betas > 0).all() and (cosine.betas <= 0.999).all()
    assert (cosine.betas[1:] >= cosine.betas[:-1]).all()


def test_unknown_schedule_raises():
    with pytest.raises(ValueError, match="Unknown beta_schedule"):
        NoiseSchedule(5, "quadratic")
    with pytest.raises(ValueError):
        NoiseSchedule(0, "vp")


def test_coefficients_are_not_saved():
    assert NoiseSchedule(5).state_dict() == {}


@pytest.mark.parametrize("name", ["vp", "linear", "cosine"])
def test_add_noise_and_inverse(name):
    schedule = NoiseSchedule(5, name)
    x0, noise = th.randn(8, 3), th.randn(8, 3)
    t = th.randint(0, 5, (8,))
    abar = schedule.alphas_cumprod[t][:, None]
    x_t = schedule.add_noise(x0, noise, t)
    assert th.allclose(x_t, abar.sqrt() * x0 + (1 - abar).sqrt() * noise, atol=1e-5)  # eq. 2
    assert th.allclose(schedule.predict_start_from_noise(x_t, t, noise), x0, atol=1e-4)


def test_posterior_matches_eq1():
    schedule = NoiseSchedule(5, "vp")
    x0, x_t, t = th.randn(4, 2), th.randn(4, 2), 3
    beta, alpha = schedule.betas[t], 1 - schedule.betas[t]
    abar, abar_prev = schedule.alphas_cumprod[t], schedule.alphas_cumprod[t - 1]
    mean, log_var = schedule.q_posterior(x0, x_t, t)
    expected_mean = beta * abar_prev.sqrt() / (1 - abar) * x0 + (1 - abar_prev) * alpha.sqrt() / (1 - abar) * x_t
    assert th.allclose(mean, expected_mean, atol=1e-6)
    assert log_var.exp().item() == pytest.approx(((1 - abar_prev) / (1 - abar) * beta).item(), rel=1e-5)


def test_step_with_exact_noise_recovers_posterior_mean_eq5():
    # with the true noise, the reverse step's mean is eq. 5's (1/sqrt(alpha_t)) (x_t - beta_t/sqrt(1-abar_t) eps)
    schedule = NoiseSchedule(5, "linear")
    x0, eps, t = th.rand(6, 2) * 0.5, th.randn(6, 2), 4
    x_t = schedule.add_noise(x0, eps, t)
    beta, abar = schedule.betas[t], schedule.alphas_cumprod[t]
    expected = (x_t - beta / (1 - abar).sqrt() * eps) / (1 - beta).sqrt()
    assert th.allclose(schedule.step(eps, t, x_t, noise=None, clip=None), expected, atol=1e-4)
    # noise is added at every step but the last
    z = th.randn(6, 2)
    assert th.allclose(schedule.step(eps, t, x_t, z, clip=None) - expected, schedule.noise_std[t] * z, atol=1e-4)
    assert th.equal(schedule.step(eps, 0, x_t, z), schedule.step(eps, 0, x_t, None))


def test_x0_is_clipped_to_action_bounds():
    schedule = NoiseSchedule(5, "vp")
    x_t = th.full((2, 1), 50.0)
    out = schedule.step(th.zeros(2, 1), 0, x_t, None, clip=1.0)
    mean, _ = schedule.q_posterior(th.ones(2, 1), x_t, 0)
    assert th.allclose(out, mean)
