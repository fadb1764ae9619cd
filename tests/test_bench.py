"""``sb3-pola bench``'s data and dynamics sections and its tables, on tiny sizes (no timings checked)."""

from __future__ import annotations

import os

from sb3_pola.benchmarks import data_bench, dynamics_bench
from sb3_pola.benchmarks.bench import format_tables

MACHINE = {"cpu": "test", "cpu_count": 2, "torch_threads": 1, "torch": "x", "device": "cpu", "date": "d", "command": "c"}


def test_data_sizes_cover_the_issue():
    """Full mode always has the 100k and 1M figures (no local datasets needed); quick mode 100k."""
    assert data_bench.synthetic_sizes(quick=False) == (100_000, 1_000_000)
    assert data_bench.synthetic_sizes(quick=True) == (100_000,)


def test_data_bench_rows_and_table(tmp_path, monkeypatch):
    monkeypatch.setattr(data_bench, "synthetic_sizes", lambda quick: (2_000, 3_000))
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "none"))  # no local datasets there
    result = data_bench.run(quick=False)
    assert os.environ["MINARI_DATASETS_PATH"] == str(tmp_path / "none")  # restored
    rows = {k: v for k, v in result.items() if k != "process_maxrss_mb"}
    assert list(rows) == ["synthetic/steps2000-v0", "synthetic/steps3000-v0"]
    for steps, row in zip((2_000, 3_000), rows.values(), strict=True):
        assert row["steps"] == steps and row["buffer_shares_memory"]
        assert row["first_load_s"] >= 0 and row["cached_load_s"] >= 0
    table = format_tables({"machine": MACHINE, "data": result, "total_s": 1.0})
    assert "| dataset | steps | first load | cached load |" in table
    assert "| synthetic/steps2000-v0 | 2,000 |" in table and "| synthetic/steps3000-v0 | 3,000 |" in table
    assert "peak RSS of the benchmark process" in table
    assert "- synthetic" not in table  # no dotted key list


def test_dynamics_table():
    fit = dynamics_bench.bench_fit(600, max_epochs=1)
    result = {"threads": 1, "load_before": 0.5, "fit": [fit], "step": {"step_deterministic_ms": 1.0}, "load_after": 0.6}
    table = format_tables({"machine": MACHINE, "dynamics": result, "total_s": 1.0})
    assert "| dynamics fit, transitions | fit time | epochs | gradient steps | ms/step |" in table
    assert f"| 600 | {fit['fit_time']:.3g} s | 1 | {int(fit['steps'])} |" in table
    assert "deterministic 1 ms" in table and "torch threads 1" in table


def test_sections_in_an_unknown_shape_stay_readable():
    table = format_tables({"machine": MACHINE, "data": {"error": "OSError: x"}, "dynamics": {"error": "boom"}, "total_s": 1.0})
    assert "- error: OSError: x" in table and "- error: boom" in table


def test_defaults_over_paper_form_checks_eager_and_compiled():
    """#23's speed target: the defaults' step over the paper form's, eager and compiled, each next to its pair."""
    from sb3_pola.benchmarks.train_bench import DEFAULTS_FORM, configurations, scaling_checks

    names = {c["name"] for c in configurations(quick=False, compiled=True)}
    assert {"defaults hopper", "defaults hopper, compiled update", "paper hopper, compiled update"} <= names
    compiled_defaults = next(c for c in configurations(False, True) if c["name"] == "defaults hopper, compiled update")
    assert compiled_defaults["kwargs"] == {**DEFAULTS_FORM, "compile_update": True}
    rows = [
        {"name": "paper hopper", "step_s": 1.0, "rollout_length": 3},
        {"name": "defaults hopper", "step_s": 1.2},
        {"name": "paper hopper, compiled update", "step_s": 0.5},
        {"name": "defaults hopper, compiled update", "step_s": 0.7},
    ]
    checks = scaling_checks(rows)
    assert checks["defaults_over_paper_form"]["met"] and abs(checks["defaults_over_paper_form"]["ratio"] - 1.2) < 1e-9
    assert not checks["defaults_over_paper_form_compiled"]["met"]
    assert abs(checks["defaults_over_paper_form_compiled"]["ratio"] - 1.4) < 1e-9


def test_train_bench_times_the_callers_configurations(monkeypatch):
    """``run(configs=...)`` builds and times the given configurations, not the benchmark's own list."""
    from sb3_pola.benchmarks import train_bench
    from sb3_pola.common.datasets import synthetic_dataset

    monkeypatch.setattr(train_bench, "synthetic_dataset", lambda n, *a: synthetic_dataset(2_000, *a))
    configs = [
        {"name": f"N={n}", "task": "hopper", "kwargs": {"n_critics": n, "batch_size": 8}, "policy_kwargs": {"net_arch": [8]}}
        for n in (2, 3)
    ]
    result = train_bench.run(quick=True, configs=configs)
    assert [r["name"] for r in result["configs"]] == ["N=2", "N=3"]
    assert [r["n_critics"] for r in result["configs"]] == [2, 3]
    assert all(r["step_s"] > 0 and r["reps"] >= 3 for r in result["configs"])
