"""The options for POLA's learning quality on locomotion data (issue #12): each behaves as documented.

The update with every option is also checked against the plain reference in ``test_reference_equivalence.py``.
"""

from __future__ import annotations

import pytest
import torch as th
from helpers import light_kwargs, model_on_dataset

from sb3_pola import PAPER_FORM, POLA
from sb3_pola.common.datasets import synthetic_dataset
from sb3_pola.common.dynamics import EnsembleDynamics
from sb3_pola.common.dynamics_trainer import DynamicsTrainer
from sb3_pola.common.schedules import WarmupSchedule, warmup_schedule
from sb3_pola.pola.pola import ensemble_similarity, lookahead_q_objective


# ---------------------------------------------------------------- eta schedule
def test_warmup_schedule_values():
    schedule = warmup_schedule(2.0, warmup=0.2, ramp=0.4)
    # progress_remaining 1 -> 0 over learn; done = 1 - progress_remaining
    assert [schedule(1.0 - done) for done in (0.0, 0.1, 0.2, 0.4, 0.6, 0.9, 1.0)] == pytest.approx(
        [0.0, 0.0, 0.0, 1.0, 2.0, 2.0, 2.0]
    )
    assert WarmupSchedule(1.0, warmup=0.5, ramp=0.0)(0.49) == 1.0  # a step
    with pytest.raises(ValueError, match="fractions"):
        WarmupSchedule(1.0, warmup=1.5)


def test_eta_schedule_is_followed_during_learn(pendulum_path, tmp_path):
    from stable_baselines3.common.logger import configure

    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(rollout_length=1, eta=warmup_schedule(1.0, 0.5, 0.0)))
    etas = []
    real_update = model._update

    def spy(batch, returns=None, actor_batch=None, next_data=None):
        stats = real_update(batch, returns, actor_batch, next_data)
        etas.append(float(stats["eta"]))
        return stats

    model._update = spy  # type: ignore[method-assign]
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(8, log_interval=4)
    assert etas == [0.0] * 4 + [1.0] * 4  # progress_remaining is taken before each step
    assert "train/eta" in (tmp_path / "progress.csv").read_text().splitlines()[0]
    # a schedule survives save/load
    model.save(tmp_path / "m")
    loaded = POLA.load(tmp_path / "m")
    assert isinstance(loaded.eta, WarmupSchedule) and loaded.eta_schedule(0.25) == 1.0


# ---------------------------------------------------------------- normalisation of the look-ahead sum and of |Q|
def test_weights_normalisation_makes_eta_independent_of_t():
    q = th.full((2, 4, 3), 2.0)  # N=2, T+1=4, B=3: the same Q everywhere
    gammas = th.tensor([1.0, 0.9, 0.81, 0.729])
    first, _ = lookahead_q_objective(q, th.ones(4, 3), gammas, top_k=1)
    weights, _ = lookahead_q_objective(q, th.ones(4, 3), gammas, top_k=1, normalization="weights")
    assert first.item() == pytest.approx(-float(gammas.sum()))  # eq. 3/4 as written: sum_i gamma^i
    assert weights.item() == pytest.approx(-1.0)  # as at T = 0


def test_q_scale_floor_bounds_the_divisor():
    q = th.full((1, 1, 4), 2.0)
    plain, _ = lookahead_q_objective(q, th.ones(1, 4), th.ones(1), top_k=1)
    floored, _ = lookahead_q_objective(q, th.ones(1, 4), th.ones(1), top_k=1, q_scale_floor=50.0)
    assert plain.item() == pytest.approx(-1.0) and floored.item() == pytest.approx(-2.0 / 50.0)
    big = th.full((1, 1, 4), 200.0)  # above the floor the batch mean |Q| divides, as in Diffusion-QL
    assert lookahead_q_objective(big, th.ones(1, 4), th.ones(1), top_k=1, q_scale_floor=50.0)[0].item() == pytest.approx(-1.0)


def test_auto_q_scale_floor_is_the_datasets_value_scale(pendulum_path, tmp_path):
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(rollout_length=0, q_scale_floor="auto"))
    assert model.q_scale_floor_value is None
    model.learn(1)
    rewards = model.replay_buffer.rewards
    assert model.q_scale_floor_value == pytest.approx(float(rewards.abs().mean()) / (1 - model.gamma), rel=1e-5)
    model.save(tmp_path / "m")
    assert POLA.load(tmp_path / "m").q_scale_floor_value == pytest.approx(model.q_scale_floor_value)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"lookahead_normalization": "sum"}, "lookahead_normalization"),
        ({"q_scale_floor": "dataset"}, "q_scale_floor"),
        ({"lookahead_uncertainty_penalty": -1.0}, "penalty"),
        ({"critic_diversity": -0.1}, "critic_diversity"),
        ({"critic_diversity": 1.0, "n_critics": 1, "top_k": 1}, "n_critics >= 2"),
        ({"critic_diversity_inputs": "states"}, "critic_diversity_inputs"),
    ],
)
def test_bad_option_values_raise(pendulum_path, kwargs, match):
    with pytest.raises(ValueError, match=match):
        POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(**kwargs))


# ---------------------------------------------------------------- a critic ensemble that disagrees off the data
def test_ensemble_similarity_is_the_mean_pairwise_cosine():
    grads = th.randn(4, 9, 3)  # [N, B, A]
    unit = grads / grads.norm(dim=-1, keepdim=True)
    gram = th.einsum("iba,jba->bij", unit, unit)  # [B, N, N]
    pairwise = (gram.sum(dim=(1, 2)) - gram.diagonal(dim1=1, dim2=2).sum(dim=1)).mean() / 3
    assert ensemble_similarity(grads).item() == pytest.approx(pairwise.item(), abs=1e-6)
    same = th.randn(1, 9, 3).expand(4, -1, -1)
    assert ensemble_similarity(same).item() == pytest.approx(4.0, abs=1e-5)  # N: every pair aligned
    opposed = th.stack([th.tensor([1.0, 0.0]), th.tensor([-1.0, 0.0])]).unsqueeze(1)  # [2, 1, 2]
    assert ensemble_similarity(opposed).item() == pytest.approx(-2.0, abs=1e-5)
    # a member with a zero action gradient: a finite similarity and finite derivatives
    flat = th.cat([th.zeros(1, 9, 3), th.randn(3, 9, 3)]).requires_grad_(True)
    ensemble_similarity(flat).backward()
    assert flat.grad is not None and th.isfinite(flat.grad).all()


def test_critic_diversity_decorrelates_the_members():
    """Trained with the term, the members' action gradients at the data are less alike than without it."""
    data = synthetic_dataset(2_000, 5, 3)
    similarity = {}
    for weight in (0.0, 1.0):
        kwargs = {
            k: v for k, v in light_kwargs(rollout_length=0, critic_diversity=weight).items() if k not in ("seed", "device")
        }
        model = model_on_dataset(data, **kwargs)
        buffer = model._setup_offline_data()
        for _ in range(200):
            stats = model._update(buffer.sample(32))
        assert ("critic_similarity" in stats) == (weight > 0)
        th.manual_seed(0)
        batch = buffer.sample(512)
        inputs = model.critic.inputs(batch.observations, batch.actions).expand(model.n_critics, -1, -1).clone()
        (grads,) = th.autograd.grad(model.critic.q_values(inputs.requires_grad_(True)).sum(), inputs)  # [N, B, in]
        similarity[weight] = ensemble_similarity(grads[..., -batch.actions.shape[-1] :]).item()
    assert similarity[1.0] < similarity[0.0] - 0.3, similarity


def test_per_member_inputs_give_each_critic_its_own(pendulum_path):
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(rollout_length=0))
    model.learn(1)
    batch = model.replay_buffer.sample(8)
    shared = model.critic(batch.observations, batch.actions)  # [N, B]
    x = model.critic.inputs(batch.observations, batch.actions)  # [B, in]
    q = model.critic.q_values(th.stack([x, -x, x]))  # [N, B, in]
    assert th.allclose(q[0], shared[0]) and th.allclose(q[2], shared[2]) and not th.allclose(q[1], shared[1])


# ---------------------------------------------------------------- the model's uncertainty in the look-ahead
def test_disagreement_is_the_elites_spread():
    model = EnsembleDynamics(3, 2, n_members=3, n_elites=2, hidden_dim=8, n_layers=1)
    obs, act = th.randn(5, 3), th.randn(5, 2)
    with th.no_grad():
        u = model.step(obs, act)[3]
        mean, _, _ = model(obs, act)
        expected = mean[model.elites][..., :3].std(dim=0).pow(2).mean(dim=-1).sqrt()
        th.testing.assert_close(u, expected)
        assert (u > 0).all()
        for layer in model.linear_layers:  # identical elites: no disagreement
            layer.weight[1].copy_(layer.weight[0])
            layer.bias[1].copy_(layer.bias[0])
        model.elites.copy_(th.tensor([0, 1]))
        assert model.step(obs, act)[3].abs().max() < 1e-6


def _lookahead_setup(dataset, batch_size):
    """A light T = 2 model after one step, a batch of its data and the actor's features of it."""
    dynamics = dict(n_members=3, n_elites=2, hidden_dim=16, n_layers=1)
    kwargs = light_kwargs(rollout_length=2, dynamics_kwargs=dynamics, lookahead_normalization="first")
    model = POLA("MlpPolicy", dataset=dataset, **kwargs)
    model.learn(1)
    obs = model.replay_buffer.sample(batch_size).observations
    return model, obs, model.policy.actor_features(obs)


def test_uncertainty_cutoff_and_penalty(pendulum_path):
    model, obs, feats = _lookahead_setup(pendulum_path, 16)
    th.manual_seed(0)
    plain_loss, plain = model._lookahead_q_loss(obs, feats)
    assert plain["lookahead_uncertainty_1"] > 0 and plain["lookahead_alive"] > 0
    assert 0 <= plain["action_saturation"] <= 1
    assert plain["policy_q_ensemble_std"] > 0
    model.lookahead_uncertainty_cutoff = 0.0  # every predicted state is too uncertain: only the current-state term
    th.manual_seed(0)
    _, cut = model._lookahead_q_loss(obs, feats)
    assert cut["lookahead_alive"] == 0 and cut["lookahead_q_1"] == 0 and cut["lookahead_q_2"] == 0
    assert cut["lookahead_q_0"] == pytest.approx(float(plain["lookahead_q_0"]))
    model.lookahead_uncertainty_cutoff = None
    model.lookahead_uncertainty_penalty = 2.0
    th.manual_seed(0)
    penalised_loss, _ = model._lookahead_q_loss(obs, feats)
    g, lam = model.gamma, model.lookahead_weight  # the penalty weighs each state as eq. 3 does
    expected = plain_loss + 2.0 * lam * (g * plain["lookahead_uncertainty_1"] + g**2 * plain["lookahead_uncertainty_2"])
    assert penalised_loss.item() == pytest.approx(expected.item(), rel=1e-5)


@pytest.mark.parametrize("rule", ["value", "bellman"])
def test_lookahead_trust_margin(pendulum_path, rule):
    model, obs, feats = _lookahead_setup(pendulum_path, 64)
    model.lookahead_trust_rule = rule  # what the margin holds against Q(s_t): Q(s_i), or the rollout's implied value

    def loss(margin):
        model.lookahead_trust_margin = margin
        th.manual_seed(0)
        return model._lookahead_q_loss(obs, feats)

    plain_loss, plain = loss(None)
    assert "lookahead_trusted" not in plain
    wide_loss, wide = loss(1e9)  # every predicted state within the margin: the paper's loss
    assert wide["lookahead_trusted"] == 1.0 and wide_loss.item() == pytest.approx(plain_loss.item(), rel=1e-6)
    none_loss, none = loss(-1e9)  # none within it: the current state's term alone
    assert none["lookahead_trusted"] == 0.0
    g, lam = model.gamma, model.lookahead_weight  # both losses divide by the same mean |Q(s_t, a_t)|
    q = [float(plain[f"lookahead_q_{i}"]) for i in range(3)]
    ratio = q[0] / (q[0] + lam * (g * q[1] + g**2 * q[2]))
    assert none_loss.item() == pytest.approx(ratio * plain_loss.item(), rel=1e-5)
    # the diagnostics keep every alive term whatever the margin
    for i in range(3):
        assert none[f"lookahead_q_{i}"] == pytest.approx(float(plain[f"lookahead_q_{i}"]), rel=1e-6)
    # a wider margin keeps more, and somewhere between the extremes it keeps some and drops others
    shares = [float(loss(m)[1]["lookahead_trusted"]) for m in (-0.1, -0.01, -0.003, -0.001, 0.0, 0.001, 0.01, 0.1)]
    assert shares == sorted(shares) and any(0.0 < share < 1.0 for share in shares)


def test_critic_bc_coef_penalises_the_target_at_the_data_next_action(pendulum_path):
    """ReBRAC's critic penalty: training hands the critic loss each row's next action in its episode and a mask that
    is 0 at the episode's last row; without the option it hands nothing."""
    calls: dict[float, list] = {}
    for coef in (0.0, 0.3):
        model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(rollout_length=0, critic_bc_coef=coef))
        critic_loss, seen = model._critic_loss_fn, calls.setdefault(coef, [])

        def spy(*args, critic_loss=critic_loss, seen=seen):
            seen.append(args[-2:])
            return critic_loss(*args)

        model._critic_loss_fn = spy
        model.learn(2)
    assert calls[0.0] == [(None, None), (None, None)]
    next_actions, goes_on = model._next_data(th.arange(len(model.replay_buffer.actions)))
    ends = model._offline_data.episode_ends()
    assert 0 < ends.sum() < len(ends) and goes_on.tolist() == (~ends).astype(float).tolist()
    within = th.as_tensor(~ends[:-1])
    assert th.equal(next_actions[:-1][within], model.replay_buffer.actions[1:][within])
    batch = light_kwargs()["batch_size"]
    assert [(a.shape, m.shape) for a, m in calls[0.3]] == [((batch, 1), (batch,))] * 2


# ---------------------------------------------------------------- the dynamics model's mean fit
def _loss_terms(mean_loss: str, beta: float = 0.5):
    th.manual_seed(0)
    model = EnsembleDynamics(3, 2, n_members=2, n_elites=1, hidden_dim=8, n_layers=1, mean_loss=mean_loss, beta=beta)
    for layer in model.linear_layers:  # no weight decay, to compare the likelihood terms alone
        layer.weight.data.zero_()
    mean = th.randn(2, 6, 4, requires_grad=True)
    logvar = th.randn(2, 6, 4).clamp(-2, 2).requires_grad_(True)
    y = th.randn(2, 6, 4)
    loss = model._loss(mean, logvar, None, y, None)
    loss.backward()
    return loss, mean, logvar, y


def test_dynamics_mean_losses():
    nll, _, logvar, _ = _loss_terms("nll")
    beta0, *_ = _loss_terms("beta_nll", beta=0.0)
    th.testing.assert_close(beta0, nll)  # beta = 0 is the NLL
    # beta = 1: the mean's gradient is the MSE's, whatever the variance
    _, mean1, _, y1 = _loss_terms("beta_nll", beta=1.0)
    th.testing.assert_close(mean1.grad, 2 * (mean1 - y1).detach() / (6 * 4))
    # mse: the mean by squared error, the variance by the NLL of the detached mean
    _, mean_m, logvar_m, y_m = _loss_terms("mse")
    th.testing.assert_close(mean_m.grad, 2 * (mean_m - y_m).detach() / (6 * 4))
    th.testing.assert_close(logvar_m.grad, logvar.grad)
    with pytest.raises(ValueError, match="mean_loss"):
        EnsembleDynamics(3, 2, mean_loss="huber")


@pytest.mark.parametrize("mean_loss", ["beta_nll", "mse"])
def test_dynamics_fit_with_each_mean_loss_beats_no_change(mean_loss):
    th.manual_seed(0)
    obs, act = th.randn(1500, 3), th.randn(1500, 2)
    next_obs = obs + 0.3 * th.tanh(act @ th.randn(2, 3)) + 0.01 * th.randn(1500, 3)
    model = EnsembleDynamics(3, 2, n_members=3, n_elites=2, hidden_dim=32, n_layers=2, mean_loss=mean_loss)
    info = DynamicsTrainer(model, max_epochs=30).fit(obs, act, next_obs, th.zeros(1500))
    assert info["holdout_mse"] < 0.1 * info["no_change_mse"]


# ---------------------------------------------------------------- the actor predict evaluates
def test_predict_actor_online_uses_the_trained_actor(pendulum_path, tmp_path):
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(rollout_length=0))
    model.learn(2)
    obs = model.replay_buffer.sample(4).observations
    feats = model.policy.actor_features(obs)

    def draw(fn):  # the same noise for every chain: seeded stochastic sampling
        th.manual_seed(7)
        with th.no_grad():
            return fn()

    with th.no_grad():
        for p in model.policy.actor.parameters():  # the online actor moves away from its EMA copy
            p.add_(0.05 * th.randn_like(p))
    ema = draw(lambda: model.policy.actor_ema.sample(feats))
    online = draw(lambda: model.policy.actor.sample(feats))
    assert not th.allclose(ema, online)
    th.testing.assert_close(draw(lambda: model.policy._predict(obs)), ema)
    model.policy.predict_actor = "online"
    th.testing.assert_close(draw(lambda: model.policy._predict(obs)), online)
    online_model = POLA(
        "MlpPolicy", dataset=pendulum_path, **light_kwargs(policy_kwargs={"net_arch": [8], "predict_actor": "online"})
    )
    online_model.save(tmp_path / "m")
    assert POLA.load(tmp_path / "m").policy.predict_actor == "online"
    with pytest.raises(ValueError, match="predict_actor"):
        POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(policy_kwargs={"net_arch": [8], "predict_actor": "x"}))


# ---------------------------------------------------------------- the paper's form (default) and the weakened one
def test_floor_and_weights_against_the_paper_form(pendulum_path):
    """The weakened form: the look-ahead sum divided by sum gamma^i, and |Q| floored at mean|r| / (1 - gamma).

    With a critic that returns the same small Q everywhere, the paper's form gives
    ``-sum_i gamma^i`` (3.94 at T = 3); the weakened form gives ``-Q / floor``, as at T = 0.
    """
    options = dict(lookahead_normalization="weights", q_scale_floor="auto")
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(rollout_length=3, **options))
    model.learn(1)
    floor = float(model.replay_buffer.rewards.abs().mean()) / (1 - model.gamma)
    assert model.q_scale_floor_value == pytest.approx(floor, rel=1e-5)
    model.lookahead_uncertainty_cutoff = None
    model._termination_fn = lambda s, a, s2: th.zeros(s.shape[0], dtype=th.bool)
    constant = 0.5 * floor
    model.critic.forward = lambda obs, act: th.full((model.n_critics, obs.shape[0]), constant)  # type: ignore[method-assign]
    obs = model.replay_buffer.sample(8).observations
    loss, _ = model._lookahead_q_loss(obs, model.policy.actor_features(obs))
    assert loss.item() == pytest.approx(-constant / floor)
    paper = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(rollout_length=3, **PAPER_FORM))
    paper.learn(1)
    paper._termination_fn = model._termination_fn
    paper.critic.forward = model.critic.forward  # type: ignore[method-assign]
    paper_loss, _ = paper._lookahead_q_loss(obs, paper.policy.actor_features(obs))
    assert paper_loss.item() == pytest.approx(-sum(paper.gamma**i for i in range(4)))


# ---------------------------------------------------------------- the defaults chosen by issue #12's measurements
def test_defaults_depart_from_the_paper_form_and_it_stays_reachable(pendulum_path):
    """The departures of issues #12 and #23 (docs/results.md); ``**PAPER_FORM`` restores the paper's form."""
    default = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs())
    paper = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(**PAPER_FORM))
    assert PAPER_FORM == {
        "eta": 1.0,
        "lookahead_weight": 1.0,
        "lookahead_normalization": "first",
        "q_scale_floor": None,
        "critic_diversity": 0.0,
        "backprop_through_model": True,
        "prediction_type": "epsilon",
        "learning_rate": 3e-4,
        "critic_layer_norm": False,
        "eta_gate": None,
        "target_q_floor": None,
        "critic_init_value": None,
        "lookahead_fixed_goal": False,
        "goal_switches": None,
        "hindsight_goals": False,
        "use_state_products": True,
        "q_term_confidence": None,
        "bc_top_fraction": None,
    }
    # the Q term at the paper's strength, bounded by LayerNorm critics (#23; #12's weakened form stays an option)
    shared = {"lookahead_normalization", "q_scale_floor"}
    for key, paper_value in PAPER_FORM.items():
        assert getattr(paper, key) == paper_value
        assert (getattr(default, key) == paper_value) == (key in shared), key
    assert default.critic_layer_norm and default.policy.critic_layer_norm and not paper.policy.critic_layer_norm
    assert any(isinstance(m, th.nn.LayerNorm) for m in default.critic.q_net)
    assert not any(isinstance(m, th.nn.LayerNorm) for m in paper.critic.q_net)
    assert (default.eta, default.lookahead_weight) == (3.94, 0.0625)  # #23's twelfth pass
    assert (default.critic_diversity, default.backprop_through_model) == (1.0, False)
    assert (default.eta_gate, default.eta_gate_fraction) == ("critic_maturity", 0.1)
    assert (default.target_q_floor, default.critic_init_value) == ("returns", "returns")
    assert default.prediction_type == "sample" and default.actor.prediction_type == "sample"
    assert paper.actor.prediction_type == "epsilon"
    # a constant 1e-3 to the end of learn (#23's thirteenth pass; the cosine decay to 0 before it)
    assert default.learning_rate == 1e-3 and default.lr_schedule(0.0) == pytest.approx(1e-3)
    # #23's twenty-ninth pass: the kernel mode of 16 samples (one sample with the observation's noise before)
    assert (default.policy.deterministic_rule, default.policy.mode_samples, default.policy.mode_bandwidth) == ("mode", 16, 0.2)
    assert default.goal_switches == "relabel"  # #23's fourteenth pass (None before)
    # #23's twenty-eighth pass: the actor on the raw state with ReLU; the paper's on the products with Mish
    kinds = {type(m) for m in default.actor.modules()}, {type(m) for m in paper.actor.modules()}
    assert not default.policy.use_state_products and th.nn.ReLU in kinds[0]
    assert paper.policy.use_state_products and th.nn.ReLU not in kinds[1]
    assert default.policy.dynamics is not None and default.policy.dynamics.mean_loss == "beta_nll"
    # in the update: the similarity term is on by default, off in the paper's form
    for model, on in ((default, True), (paper, False)):
        model.learn(1)
        assert ("critic_similarity" in model._update(model.replay_buffer.sample(32))) == on


def test_main_job_runs_the_package_defaults_and_light_paper_keeps_the_papers_form():
    """#23: the shipped main job (`make train`, ``--config light``) is the package defaults at the light sizes; the
    paper's form at those sizes, as the main job ran before, is ``--config light-paper``."""
    from sb3_pola.cli.run import CONFIGS, LIGHT_SIZES, parse_args

    assert parse_args([]).config == "light"
    assert CONFIGS["light"] is LIGHT_SIZES and CONFIGS["defaults"] is LIGHT_SIZES  # "defaults": the earlier name
    for config in (CONFIGS["light-paper"], CONFIGS["paper"]):
        assert {key: config[key] for key in PAPER_FORM if key != "learning_rate"} == {
            key: value for key, value in PAPER_FORM.items() if key != "learning_rate"
        }
    assert CONFIGS["light-paper"]["learning_rate"] == 1e-3  # the light job's own, as measured
    # the pole needs the chain's mean under the paper's form: that job evaluates with the noise-free rule
    assert CONFIGS["light-paper"]["policy_kwargs"]["deterministic_rule"] == "noise_free"


def test_run_config_light_is_the_package_defaults_at_the_light_sizes(pendulum_path):
    """``sb3-pola run`` (#23): the light job's sizes and budgets, every algorithmic choice the package's default;
    ``light-paper`` is these sizes plus the paper's form."""
    from sb3_pola.cli.run import CONFIGS

    light = CONFIGS["light"]
    assert not set(light) & (set(PAPER_FORM) | {"lcb_coef", "eta", "eta_gate", "reward_scale"})
    assert set(light["policy_kwargs"]) == {"net_arch"}
    assert "mean_loss" not in light["dynamics_kwargs"]
    paper = CONFIGS["light-paper"]
    for key, value in light.items():
        if isinstance(value, dict):
            assert value.items() <= paper[key].items(), key
        else:
            assert paper[key] == value, key


@pytest.mark.parametrize("compile_activations", [False, True])
def test_critic_second_derivative_is_finite_at_large_activations(compile_activations):
    """F.mish's second derivative is NaN above about 90; the critic's Mish under eager_activations is not."""
    from torch.nn import functional as F

    from sb3_pola.common.activations import FusedMish, TwiceDifferentiableMish, eager_activations

    x = th.tensor([-200.0, -30.0, 0.0, 30.0, 95.0, 200.0], requires_grad=True)
    (g,) = th.autograd.grad(F.mish(x).sum(), x, create_graph=True)
    assert not th.isfinite(th.autograd.grad(g.sum(), x)[0]).all()  # the failure this guards against
    module = FusedMish() if compile_activations else TwiceDifferentiableMish()
    with eager_activations():
        y = module(x)
        (g,) = th.autograd.grad(y.sum(), x, create_graph=True)
        (h,) = th.autograd.grad(g.sum(), x)
    assert th.allclose(y, F.mish(x)) and th.isfinite(h).all()
    assert th.allclose(TwiceDifferentiableMish()(x), F.mish(x))  # outside the block: F.mish itself


# ---------------------------------------------------------------- q_term_confidence
def _q_term_on_fixed_draws(model, obs, actions):
    """The actor step's Q term with the data's actions, on fixed draws (seed 1)."""
    th.manual_seed(1)
    with model._critic_frozen():
        return model._q_term(obs, model._eta_value, actions)


def test_q_term_confidence_counts_a_state_where_the_members_agree_its_action_beats_the_datas(pendulum_path):
    kwargs = light_kwargs(n_critics=4, q_term_confidence=0.0)
    del kwargs["seed"], kwargs["device"]
    model = model_on_dataset(pendulum_path, **kwargs)
    obs, actions = model.replay_buffer.observations[:64], model.replay_buffer.actions[:64]
    _, stats = _q_term_on_fixed_draws(model, obs, actions)
    th.manual_seed(1)  # the actor's action at s_t is the Q term's first draw
    with th.no_grad():
        gain = model.critic(obs, model._sample_actor(model.policy.actor_features(obs))) - model.critic(obs, actions)
    want = (gain.mean(dim=0) > 0).float().mean()  # [N, B] -> the share of states whose members agree
    assert 0.0 < float(want) < 1.0
    th.testing.assert_close(stats["q_term_share"], want)

    model.q_term_confidence = 1e9  # no state passes: no Q gradient reaches the actor
    loss, stats = _q_term_on_fixed_draws(model, obs, actions)
    assert float(stats["q_term_share"]) == 0.0 and float(loss.detach()) == 0.0
    model.actor.zero_grad(set_to_none=True)
    loss.backward()
    assert all(p.grad is None or not p.grad.any() for p in model.actor.parameters())

    model.q_term_confidence = -1e9  # every state passes: the paper's Q term on the same draws
    gated, stats = _q_term_on_fixed_draws(model, obs, actions)
    model.q_term_confidence = None
    plain, stats_plain = _q_term_on_fixed_draws(model, obs, actions)
    assert float(stats["q_term_share"]) == 1.0 and "q_term_share" not in stats_plain
    th.testing.assert_close(gated, plain, rtol=0, atol=0)


def test_q_term_confidence_share_is_logged_in_training(pendulum_path):
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(n_critics=3, q_term_confidence=1.0))
    model.learn(4)
    assert 0.0 <= model.logger.name_to_value["train/q_term_share"] <= 1.0


# ---------------------------------------------------------------- bc_top_fraction (filtered BC for the actor)
def test_bc_top_fraction_draws_the_actors_batches_from_the_best_episodes(pendulum_path, tmp_path):
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(bc_top_fraction=0.3))
    data = model.offline_data
    best = set(data.best_episode_rows(0.3).tolist())
    assert 0 < len(best) < len(data)  # the fixture's best of three episodes
    seen = {"actor": set(), "critic": 0}
    update = model._update

    def spy(batch, returns, actor_batch, next_data):
        observations = model._setup_offline_data().observations
        for row in actor_batch[0]:  # the rows of the actor's observations (the pendulum's states are distinct)
            seen["actor"].add(int(th.nonzero((observations == row).all(dim=1))[0, 0]))
        seen["critic"] += len(batch.observations)
        return update(batch, returns, actor_batch, next_data)

    model._update = spy
    model.learn(5)
    assert seen["actor"] and seen["actor"] <= best
    assert seen["critic"] == 5 * model.batch_size  # the critics keep the uniform batch over every transition
    model.save(tmp_path / "m")  # the rows are the data's: rebuilt, not saved
    loaded = POLA.load(tmp_path / "m", dataset=pendulum_path)
    loaded.learn(1, reset_num_timesteps=False)
    assert set(loaded._imitation_rows.tolist()) == best


def test_dense_reward_options_are_on_by_default_without_a_goal(pendulum_path):
    """``q_term_confidence`` and ``bc_top_fraction`` default to ``"auto"``: on data without a ``desired_goal`` their
    dense-reward values (fortieth pass), the gate's share logged; off with one critic, or when given ``None``."""
    model = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs())
    assert (model.q_term_confidence, model.bc_top_fraction) == ("auto", "auto")
    assert model._dense_option("q_term_confidence") == 1.0 and model._dense_option("bc_top_fraction") == 0.1
    assert set(model._imitation_rows.tolist()) == set(model.offline_data.best_episode_rows(0.1).tolist())
    model.learn(4)
    assert 0.0 <= model.logger.name_to_value["train/q_term_share"] <= 1.0
    given = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(q_term_confidence=1.0, bc_top_fraction=0.1))
    given.learn(4)  # "auto" trains as the values it stands for, draw for draw
    assert all(th.equal(a, b) for a, b in zip(model.policy.parameters(), given.policy.parameters(), strict=True))
    single = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(n_critics=1, top_k=1, critic_diversity=0.0))
    assert single._dense_option("q_term_confidence") is None  # no members to agree
    paper = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(q_term_confidence=None, bc_top_fraction=None))
    assert paper._dense_option("q_term_confidence") is None and paper._imitation_rows is None
    paper.learn(4)
    assert "train/q_term_share" not in paper.logger.name_to_value


def test_bc_top_fraction_must_be_a_share_of_the_episodes(pendulum_path):
    for value in (0.0, 1.5):
        with pytest.raises(ValueError, match="bc_top_fraction"):
            POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(bc_top_fraction=value))
