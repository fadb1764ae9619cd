"""``experiments/policy_quality/confident_choice.py``: the choice between POLA's and BC's action by POLA's critic."""

from __future__ import annotations

import importlib.util
import json
import pathlib

import numpy as np
import torch as th
from helpers import light_kwargs

from sb3_pola import POLA

SCRIPT = pathlib.Path(__file__).resolve().parents[1] / "experiments" / "policy_quality" / "confident_choice.py"


def _script():
    spec = importlib.util.spec_from_file_location("confident_choice", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_choice_follows_the_members_test_of_the_gain(pendulum_path):
    module = _script()
    pola = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(rollout_length=0, n_critics=4))
    bc = POLA("MlpPolicy", dataset=pendulum_path, **light_kwargs(rollout_length=0, eta=0.0, seed=1))
    observations = pola.replay_buffer.observations[:40].numpy()
    for k in (-1e9, 1e9):  # every action POLA's, every action BC's
        choice = module.ConfidentChoice(pola, bc, k)
        for obs in observations:
            action, _ = choice.predict(obs)
            want = (pola if k < 0 else bc).predict(obs, deterministic=True)[0]
            np.testing.assert_array_equal(action, want)
        assert choice.took_pola == [k < 0] * len(observations)
    ratios = []  # the members' mean gain over their spread at each state
    for obs in observations:
        a_pola, a_bc = (m.predict(obs, deterministic=True)[0] for m in (pola, bc))
        with th.no_grad():
            q = pola.policy.critic(th.as_tensor(np.stack([obs, obs])), th.as_tensor(np.stack([a_pola, a_bc])))
        gain = q[:, 0] - q[:, 1]
        ratios.append(float(gain.mean() / gain.std()))
    k = float(np.median(ratios))  # in between: POLA's action where the ratio beats k, about half the states
    choice = module.ConfidentChoice(pola, bc, k)
    for obs in observations:
        choice.predict(obs)
    taken = [r > k for r in ratios]
    assert choice.took_pola == taken and 0 < sum(taken) < len(taken)


def test_model_choice_runs_the_packages_rule_at_each_k(pendulum_path):
    """``--model``: one model with the package's fallback actor, evaluated at another ``k`` (its own actor alone, its
    imitation actor alone, the rule between), the steps on its own action counted."""
    module = _script()
    kwargs = light_kwargs(rollout_length=0, n_critics=4, policy_kwargs={"net_arch": [32, 32], "fallback_confidence": 2.0})
    model = POLA("MlpPolicy", dataset=pendulum_path, **kwargs)
    model.learn(30)
    observations = model.replay_buffer.observations[:40].numpy()
    policy = model.policy
    with th.no_grad():
        own = policy.unscale_action(policy._actor_action(policy.actor_ema, th.as_tensor(observations), True).numpy())
    shares = {}
    for k in (module.EXTREMES["pola"], module.EXTREMES["bc"], 0.0):
        choice = module.ModelChoice(model, k)
        actions = np.concatenate([choice.predict(obs[None])[0] for obs in observations])
        shares[k] = float(np.mean(choice.took_pola))
        np.testing.assert_array_equal(np.all(actions == own, axis=1), choice.took_pola)
        assert model.policy.fallback_confidence == k
    assert shares[module.EXTREMES["pola"]] == 1.0 and shares[module.EXTREMES["bc"]] == 0.0
    # the data share: the same rule on data states, in one batch
    assert module.data_share(model, observations, module.EXTREMES["pola"]) == 1.0
    assert module.data_share(model, observations, module.EXTREMES["bc"]) == 0.0
    choice = module.ModelChoice(model, 0.5)
    for obs in observations:
        choice.predict(obs[None])
    # one batch against one row at a time: where both actors' actions nearly agree, the gains are float32 noise
    # (~1e-5) whose mean/std ratio can land on either side of k; at most one such state of the 40 here
    assert abs(module.data_share(model, observations, 0.5) - np.mean(choice.took_pola)) <= 1 / len(observations)


def test_choice_table_pairs_each_k_with_either_actor(tmp_path: pathlib.Path):
    spec = importlib.util.spec_from_file_location("choice_table", SCRIPT.parent / "choice_table.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    rows = [
        {
            "dataset": "d",
            "seed": s,
            "pola": p,
            "bc": b,
            "k1": k,
            "pola_pola_share": 1.0,
            "bc_pola_share": 0.0,
            "k1_pola_share": 0.5,
        }
        for s, p, b, k in ((0, 30.0, 40.0, 36.0), (1, 32.0, 44.0, 40.0), (2, 31.0, 42.0, 38.0))
    ]
    rows.append({"dataset": "d", "seed": 0, "k1": 0.0})  # an offline row of two models: not this table's
    path = tmp_path / "rows.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    cells = module.read(path, None)
    assert list(cells) == ["d"] and sorted(cells["d"]) == [0, 1, 2]
    line = next(line for line in module.table(cells).splitlines() if "| k1 |" in line)
    # k1 - pola: 6, 8, 7 -> 7.0 ± 0.6; k1 - bc: -4, -4, -4 -> -4.0 ± 0.0
    assert "| 38.0 ± 2.0 | +7.0 ± 0.6 | -4.0 ± 0.0 | 0.50 |" in line
