"""``sb3-pola score``: runs, outputs, resume and skip, on a tiny Pendulum dataset (never ../shared)."""

from __future__ import annotations

import json
import math
import os
import pathlib

import numpy as np
import pytest
import torch as th
from helpers import TINY_GRID

from sb3_pola.cli import score as score_cli
from sb3_pola.common.errors import UsageError
from sb3_pola.grid import cell as grid_cell
from sb3_pola.grid import diagnostics
from sb3_pola.grid import reevaluate as reeval
from sb3_pola.grid import report as grid_report
from sb3_pola.grid import rows as grid_rows
from sb3_pola.grid import variants as grid_variants

TINY = ["--steps", "6", "--eval-freq", "3", "--eval-episodes", "1", *TINY_GRID]


def run(root: pathlib.Path, out: pathlib.Path, *extra: str) -> int:
    return score_cli.main([*TINY, "--data-dir", str(root), "--datasets", "test/pendulum-v0", "--out", str(out), *extra])


def test_score_end_to_end_and_skip(score_data: pathlib.Path, tmp_path: pathlib.Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "out"
    assert run(score_data, out, "--variants", "T0", "T1", "BC", "--seeds", "0", "1") == 0
    rows = grid_rows.read_rows(out / "scores.csv")
    # 3 variants x 2 seeds x evaluations at steps 3 and 6
    assert len(rows) == 12
    assert {(r["variant"], r["seed"], r["step"]) for r in rows} == {
        (v, s, t) for v in ("T0", "T1", "BC") for s in (0, 1) for t in (3, 6)
    }
    assert all(np.isfinite(r["score"]) and r["eval_episodes"] == 1 for r in rows)
    table = (out / "table.md").read_text()
    assert "| test/pendulum-v0 | T1 |" in table and "| test/pendulum-v0 | BC |" in table
    assert (out / "fig_rollout_test_pendulum-v0.png").stat().st_size < 200_000
    assert not (out / "fig_products_test_pendulum-v0.png").exists()  # needs two product variants
    assert sorted(p.name for p in (out / "dynamics").iterdir()) == ["test_pendulum-v0__shared.pt"]  # fitted once, shared
    assert not list((out / "ckpt").iterdir())  # checkpoints of finished runs are removed
    config = json.loads((out / "config.json").read_text())
    assert config["steps"] == 6 and config["device"] == "cpu" and config["net_arch"] == [8]
    # the same command again: every run is skipped, nothing is added
    capsys.readouterr()
    assert run(score_data, out, "--variants", "T0", "T1", "BC", "--seeds", "0", "1", "-v", "1") == 0
    assert capsys.readouterr().out.count("done, skipped") == 6
    assert len(grid_rows.read_rows(out / "scores.csv")) == 12
    # another budget in the same folder is refused
    assert run(score_data, out, "--variants", "T0", "--seeds", "0", "--steps", "9") == 2


def test_data_dir_is_restored(score_data: pathlib.Path, tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``--data-dir`` sets MINARI_DATASETS_PATH for the command only."""
    before = str(tmp_path / "elsewhere")
    monkeypatch.setenv("MINARI_DATASETS_PATH", before)
    assert run(score_data, tmp_path / "out", "--variants", "T0", "--seeds", "0", "--dry-run") == 0
    assert os.environ["MINARI_DATASETS_PATH"] == before


def test_score_resumes_an_interrupted_run(
    score_data: pathlib.Path, tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "out"
    real_evaluate = grid_cell.evaluate
    calls = []

    def interrupted(*args, **kwargs):  # the second evaluation never happens: the process "dies" at step 6
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real_evaluate(*args, **kwargs)

    monkeypatch.setattr(grid_cell, "evaluate", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run(score_data, out, "--variants", "T3-noproducts", "--seeds", "0", "--steps", "9")
    assert [r["step"] for r in grid_rows.read_rows(out / "scores.csv")] == [3]
    assert (out / "ckpt" / "test_pendulum-v0__T3-noproducts__seed0.zip").exists()
    monkeypatch.setattr(grid_cell, "evaluate", real_evaluate)
    assert run(score_data, out, "--variants", "T3-noproducts", "--seeds", "0", "--steps", "9") == 0
    rows = grid_rows.read_rows(out / "scores.csv")
    assert [r["step"] for r in rows] == [3, 6, 9]
    assert rows[2]["wall_s"] >= rows[0]["wall_s"]
    marker = json.loads((out / "cells" / "test_pendulum-v0__T3-noproducts__seed0.json").read_text())
    assert marker["steps"] == 9


def test_report_from_csv(tmp_path: pathlib.Path) -> None:
    """Table (final/best, mean ± sample std over seeds, paper column) and both figures from a hand-written CSV."""
    rows = []
    for variant, base in [("T0", 10.0), ("T3", 20.0), ("T3-noproducts", 15.0), ("T3-criticproducts", 5.0), ("BC", 8.0)]:
        for seed in (0, 1):
            for step, bump in [(100, 0.0), (200, 4.0), (300, 2.0)]:
                rows.append(
                    dict(
                        dataset="halfcheetah/medium-v0",
                        variant=variant,
                        seed=seed,
                        step=step,
                        score=base + bump + 2 * seed,
                        score_std=1.0,
                        mean_return=0.0,
                        eval_episodes=2,
                        wall_s=float(step),
                    )
                )
    out = tmp_path / "r"
    out.mkdir()
    grid_rows.write_rows(out / "scores.csv", rows)
    assert (
        score_cli.main(
            ["--report-only", "--out", str(out), "--variants", "T0", "T3", "T3-noproducts", "T3-criticproducts", "BC"]
        )
        == 0
    )
    table = (out / "table.md").read_text()
    # T3: final = 22, 24 -> 23.0 ± 1.4; best = 24, 26 -> 25.0 ± 1.4; paper's halfcheetah-medium POLA 71.8
    assert "| halfcheetah/medium-v0 | T3 | 23.0 ± 1.4 | 25.0 ± 1.4 | 0,1 | 300 |" in table
    assert "71.8 ± 0.4" in table
    assert table.index("| T0 |") < table.index("| T3 |") < table.index("| BC |")
    for name in ("fig_rollout_halfcheetah_medium-v0.png", "fig_products_halfcheetah_medium-v0.png"):
        assert 0 < (out / name).stat().st_size < 200_000


@pytest.mark.parametrize(
    "dataset, task",
    [
        ("halfcheetah/medium-v0", ("halfcheetah", "medium")),
        ("halfcheetah/medium-replay-v0", ("halfcheetah", "medium-replay")),
        ("mujoco/walker2d/medium-expert-v0", ("walker2d", "medium-expert")),
        ("hopper-random-v2", ("hopper", "random")),
        ("halfcheetah/expert-v0", None),
        ("pendulum/medium-v0", None),
    ],
)
def test_paper_task(dataset: str, task: tuple[str, str] | None) -> None:
    assert grid_variants.paper_task(dataset) == task


def test_presets_and_overrides() -> None:
    args = score_cli.parse_args(["--steps", "50", "--n-critics", "1", "--net-arch", "32", "32"])
    cpu = grid_variants.build_config(args, "cpu")
    assert (cpu.preset, cpu.steps, cpu.n_critics, cpu.top_k, cpu.net_arch) == ("cpu", 50, 1, 1, [32, 32])
    assert cpu.eval_freq == grid_variants.PRESETS["cpu"].eval_freq
    paper = grid_variants.build_config(score_cli.parse_args([]), "cuda")
    assert (paper.preset, paper.n_critics, paper.net_arch, paper.batch_size) == ("paper", 10, [256, 256, 256], 256)
    assert cpu.signature() != grid_variants.build_config(score_cli.parse_args(["--steps", "51"]), "cpu").signature()
    with pytest.raises(UsageError, match="argument --variants: invalid choice"):
        score_cli.parse_args(["--variants", "T7"])


def test_extra_refuses_arguments_with_their_own_flag() -> None:
    """POLA would get ``n_critics`` twice (the cell passes the preset's) and fail only when the first cell starts."""
    for key, flag in (("n_critics", "--n-critics"), ("batch_size", "--batch-size"), ("dynamics_kwargs", "--dynamics-kwargs")):
        args = score_cli.parse_args(["--preset", "cpu", "--extra", json.dumps({key: 10, "eta": 1.0})])
        with pytest.raises(UsageError, match=f"{key} \\(use {flag}\\)"):
            grid_variants.build_config(args, "cpu")
    config = grid_variants.build_config(score_cli.parse_args(["--preset", "cpu", "--n-critics", "10"]), "cpu")
    assert config.n_critics == 10


def test_extra_policy_kwargs_reach_the_policy(score_data: pathlib.Path) -> None:
    """A ``policy_kwargs`` entry of ``--extra`` adds to the preset's policy arguments instead of clashing with them."""
    extra = json.dumps({"policy_kwargs": {"time_embedding_dim": 8}})
    config = grid_variants.build_config(score_cli.parse_args([*TINY, "--preset", "cpu", "--extra", extra]), "cpu")
    model = grid_cell.new_cell_model("T0", 0, config, "test/pendulum-v0", "cpu")
    assert model.policy.time_embedding_dim == 8
    assert model.policy_kwargs["net_arch"] == config.net_arch


def test_cpu_preset_actor_is_2x256_relu_on_the_raw_state(score_data: pathlib.Path) -> None:
    """#23's twenty-eighth pass: the CPU preset's actor 2 x 256 with ReLU on the raw state, its critics 2 x 128 with
    Mish; the ``-products`` variants give the actor the paper's products and Mish."""
    config = grid_variants.build_config(score_cli.parse_args(["--preset", "cpu", "--no-compile"]), "cpu")
    assert config.net_arch == {"pi": [256, 256], "qf": [128, 128]}
    model = grid_cell.new_cell_model("T3", 0, config, "test/pendulum-v0", "cpu")
    actor_kinds = {type(m) for m in model.actor.modules()}
    assert th.nn.ReLU in actor_kinds and th.nn.Mish not in actor_kinds
    assert model.policy.features_extractor.features_dim == 3  # Pendulum's raw state
    assert {m.out_features for m in model.actor.modules() if isinstance(m, th.nn.Linear)} >= {256}
    assert max(m.out_features for m in model.critic.modules() if hasattr(m, "ensemble_size")) == 128
    paper_actor = grid_cell.new_cell_model("T3-products", 0, config, "test/pendulum-v0", "cpu")
    assert paper_actor.policy.features_extractor.features_dim == 3 + 3
    assert th.nn.ReLU not in {type(m) for m in paper_actor.actor.modules()}
    both = grid_cell.new_cell_model("T3-criticproducts", 0, config, "test/pendulum-v0", "cpu")
    assert both.policy.features_extractor.features_dim == both.critic.features_extractor.features_dim == 6


def test_cells_keep_statistics_and_models_and_reevaluate(score_data: pathlib.Path, tmp_path: pathlib.Path) -> None:
    """Every cell writes its training statistics and keeps its final model; --reevaluate scores it under other rules."""
    out = tmp_path / "out"
    assert run(score_data, out, "--variants", "T1", "--seeds", "0", "--log-interval", "2") == 0
    name = "test_pendulum-v0__T1__seed0"
    train_rows = diagnostics.read_train_stats(out / "train" / name)
    assert [r["time/total_timesteps"] for r in train_rows] == [2, 4, 6]
    for key in ("train/bc_loss", "train/q_loss", "train/lookahead_q_1", "train/lookahead_alive", "train/actor_grad_norm"):
        assert all(key in r for r in train_rows), key
    assert all(0 <= r["train/action_saturation"] <= 1 for r in train_rows)
    assert (out / "models" / f"{name}.zip").exists()
    final = grid_rows.read_rows(out / "scores.csv")[-1]
    rules = ["ema", "online", "candidates3", "stochastic"]
    assert score_cli.main(["--out", str(out), "--reevaluate", *rules, "-v", "0"]) == 0
    rows = {r["rule"]: r for r in reeval.reevaluate(out, ["ema"], 1, "cpu", verbose=0)}  # already done: skipped, read back
    assert set(rows) == set(rules)
    assert float(rows["ema"]["score"]) == pytest.approx(final["score"])  # same rule, same resets: the run's final score
    assert "| test/pendulum-v0 | T1 | candidates3 |" in (out / "reeval.md").read_text()
    (out / "reeval.csv").unlink()
    again = reeval.reevaluate(out, ["stochastic"], 1, "cpu", verbose=0)
    assert float(again[-1]["mean_return"]) == pytest.approx(float(rows["stochastic"]["mean_return"]))  # seeded sampling
    with pytest.raises(ValueError, match="unknown evaluation rule"):
        score_cli.main(["--out", str(out), "--reevaluate", "best-of-3"])
    # diagnostics.md: the end-of-training statistics of the cell, with the look-ahead growth q_1 / q_0
    table = (out / "diagnostics.md").read_text()
    row = next(line for line in table.splitlines() if line.startswith(f"| {name} |"))
    summary = diagnostics.summarize_cell(train_rows)
    assert summary["lookahead_growth"] == pytest.approx(summary["lookahead_q_1"] / summary["lookahead_q_0"])
    assert row.split(" | ")[1] == "6"
    assert diagnostics.plot_lookahead(out) == out / "fig_lookahead.png"


def test_eval_rules() -> None:
    assert grid_variants.parse_eval_rule("ema") == ("ema", 1, True)
    assert grid_variants.parse_eval_rule("online-stochastic") == ("online", 1, False)
    assert grid_variants.parse_eval_rule("candidates10") == ("ema", 10, True)
    assert grid_variants.parse_eval_rule("online-candidates2") == ("online", 2, True)
    for bad in ("candidates0", "stochastic3", "best"):
        with pytest.raises(ValueError, match="unknown evaluation rule"):
            grid_variants.parse_eval_rule(bad)


def test_eta_warmup_from_json() -> None:
    from sb3_pola.common.schedules import WarmupSchedule

    kwargs = grid_variants.pola_kwargs({"eta_warmup": [0.5, 0.2], "eta": 2.0, "rollout_length": 3})
    assert isinstance(kwargs["eta"], WarmupSchedule) and kwargs["eta"](0.2) == 2.0 and kwargs["eta"](0.6) == 0.0
    assert kwargs["rollout_length"] == 3 and "eta_warmup" not in kwargs
    assert grid_variants.pola_kwargs({"eta_warmup": [0.5, 0.2], "eta": 0.0})["eta"] == 0.0  # BC stays BC
    assert grid_variants.pola_kwargs({"eta_warmup": [0.5, 0.2]})["eta"](0.2) == 3.94  # the package default


def test_cosine_learning_rate_from_json() -> None:
    """``"lr_cos"`` reproduces the runs made before the constant learning rate became the default (#23)."""
    from sb3_pola.common.schedules import CosineSchedule

    kwargs = grid_variants.pola_kwargs({"lr_cos": 1e-3, "eta": 2.0})
    assert isinstance(kwargs["learning_rate"], CosineSchedule) and "lr_cos" not in kwargs
    assert kwargs["learning_rate"](1.0) == pytest.approx(1e-3) and kwargs["learning_rate"](0.0) == 0.0
    assert "learning_rate" not in grid_variants.pola_kwargs({"eta": 2.0})  # the package default: 1e-3, constant
    late = grid_variants.pola_kwargs({"lr_cos": [1e-3, 1e-4, 0.5]})["learning_rate"]
    assert (late.initial, late.final, late.start) == (1e-3, 1e-4, 0.5) and late(0.6) == pytest.approx(1e-3)
    bc = grid_variants.pola_kwargs({"bc_lr_cos": 1e-3})  # the imitation term's own rate
    assert isinstance(bc["bc_learning_rate"], CosineSchedule) and "learning_rate" not in bc and "bc_lr_cos" not in bc


def test_eval_rule_during_training(score_data: pathlib.Path, tmp_path: pathlib.Path) -> None:
    """--eval-rule stochastic scores with one seeded sample of the chain and leaves training as it was."""
    import torch as th

    from sb3_pola import POLA

    # the rule's default leaves a signature as it was before the option existed; the defaults that departed from
    # the paper's form changed it (cpu: cd99bea051, paper: f8a0da1694 before #12; 05ed254249, 6863b1ac8a before #23;
    # 46209b7d80, 824efa1128 before #23's LayerNorm critics; c8dd8105f2, 4c8e7685a9 before #23's maturity gate, whose
    # explicit eta_gate=None in PAPER_FORM changes the paper's too; 08455f37e6, 97f527da8d before #23's "returns" floor
    # and critic start; 7094a5d722, c1594669b0 before #23's fixed goal in the look-ahead; 20c38ed775, e9625c50e1 before
    # #23's eta 3.94 and lookahead_weight 1/16, which PAPER_FORM now names; bd27d4080b, 9f44ccef5c before #23's
    # constant learning rate; 888d5085a7, 414bf21ef7 before #23's relabelled goal switches; 7ab4808cde, 1275fa6ebf
    # before #23's hindsight goals; cedcb37962, ceb7361daf before #23's actor on the raw state and the cpu preset's
    # 2 x 256 actor; 22f4ffa045, 0c8cbe3377 before #23's "auto" q_term_confidence and bc_top_fraction), so that a
    # folder of the old defaults is not resumed under the new ones
    presets = grid_variants.PRESETS
    assert presets["cpu"].signature() == "a9fbd00aaf" and presets["paper"].signature() == "3525bdef14"
    base, sampled = tmp_path / "ema", tmp_path / "stochastic"
    assert run(score_data, base, "--variants", "T1", "--seeds", "0") == 0
    assert run(score_data, sampled, "--variants", "T1", "--seeds", "0", "--eval-rule", "stochastic") == 0
    assert json.loads((sampled / "config.json").read_text())["eval_rule"] == "stochastic"
    assert "evaluation rule `stochastic`" in (sampled / "table.md").read_text()
    name = "test_pendulum-v0__T1__seed0.zip"
    params = [POLA.load(folder / "models" / name, device="cpu").policy.state_dict() for folder in (base, sampled)]
    assert all(th.equal(params[0][key], params[1][key]) for key in params[0])  # the evaluation drew no training noise
    final = grid_rows.read_rows(sampled / "scores.csv")[-1]
    again = {r["rule"]: r for r in reeval.reevaluate(sampled, ["stochastic", "ema"], 1, "cpu", verbose=0)}
    assert float(again["stochastic"]["mean_return"]) == pytest.approx(final["mean_return"])
    assert float(again["ema"]["mean_return"]) == pytest.approx(grid_rows.read_rows(base / "scores.csv")[-1]["mean_return"])
    with pytest.raises(ValueError, match="unknown evaluation rule"):
        run(score_data, tmp_path / "bad", "--variants", "T1", "--eval-rule", "best")


class _GoalEnv:
    """Three-step episodes; ``info["success"]`` is true at the last step of every other episode."""

    def __init__(self) -> None:
        self.episode, self.t = -1, 0

    def reset(self, seed: int | None = None):
        self.episode, self.t = self.episode + 1, 0
        return np.zeros(2, dtype=np.float32), {}

    def step(self, action):
        self.t += 1
        done = self.t == 3
        return np.zeros(2, dtype=np.float32), 1.0, done, False, {"success": done and self.episode % 2 == 0}


class _ConstantModel:
    def predict(self, obs, deterministic=True):
        return np.zeros(1, dtype=np.float32), None

    def normalized_score(self, returns):
        return 100.0 * returns / 3.0


def test_success_rate_column(tmp_path: pathlib.Path) -> None:
    """Goal-reaching envs: the success rate of an evaluation, in scores.csv and table.md; old files keep working."""
    scores = grid_cell.evaluation_scores(_ConstantModel(), _GoalEnv(), 4, seed=0)
    assert scores["success"] == 0.5 and scores["score"] == 100.0
    assert math.isnan(grid_cell.evaluation_scores(_ConstantModel(), _ConstantEnvWithoutSuccess(), 2, seed=0)["success"])
    # a scores.csv from before the column: appending rewrites it with the column, old rows get NaN
    csv_path = tmp_path / "scores.csv"
    old_fields = [f for f in grid_rows.CSV_FIELDS if f != "success"]
    row = {"dataset": "d", "variant": "T0", "seed": 0, "step": 5, "score": 1.0, "score_std": 0.0, "mean_return": 3.0}
    row |= {"eval_episodes": 4, "wall_s": 1.0}
    csv_path.write_text(",".join(old_fields) + "\n" + ",".join(str(row[f]) for f in old_fields) + "\n")
    assert math.isnan(grid_rows.read_rows(csv_path)[0]["success"])
    grid_rows.append_row(csv_path, {**row, "step": 10, **scores})
    assert csv_path.read_text().splitlines()[0] == ",".join(grid_rows.CSV_FIELDS)
    rows = grid_rows.read_rows(csv_path)
    assert math.isnan(rows[0]["success"]) and rows[1]["success"] == 0.5
    table = grid_report.markdown_table(rows, ["T0"])
    assert "final success rate" in table and "| 0.50 |" in table
    assert "success rate" not in grid_report.markdown_table([{**r, "success": math.nan} for r in rows], ["T0"])


class _ConstantEnvWithoutSuccess(_GoalEnv):
    def step(self, action):
        obs, reward, terminated, truncated, _ = super().step(action)
        return obs, reward, terminated, truncated, {}
