"""``sb3-pola bench``: POLA's speed and memory benchmarks, printed as a table next to their targets and saved as JSON.

Sections: gradient steps per second over configurations with FLOPs and roofline fraction
(:mod:`~sb3_pola.benchmarks.train_bench`), predict latency and throughput (:mod:`~sb3_pola.benchmarks.predict_bench`),
the exported policy's latency under ONNX Runtime and TorchScript (:mod:`~sb3_pola.benchmarks.export_bench`, CPU),
dataset load time and memory (:mod:`~sb3_pola.benchmarks.data_bench`) and the dynamics model's fit time
(:mod:`~sb3_pola.benchmarks.dynamics_bench`). Timings are medians after warm-up. ``--quick`` runs a
reduced set (fewer configurations, sizes and repetitions) as a smoke check. Runs unchanged on CUDA (``--device cuda``).
"""

from __future__ import annotations

import datetime
import importlib
import json
import os
import pathlib
import platform
import sys
import time
import traceback
from typing import Any

import torch as th

from sb3_pola.common.arguments import ArgumentParser
from sb3_pola.common.extras import missing_extra, missing_extra_message
from sb3_pola.common.machine import cpu_name, gpu_name

SECTIONS = ("train", "predict", "export", "data", "dynamics")


def machine_info(device: str) -> dict[str, Any]:
    """The machine and the command of a benchmark run (:mod:`sb3_pola.common.machine`), for the results' JSON."""
    info: dict[str, Any] = {
        "cpu": cpu_name(),
        "cpu_count": os.cpu_count(),
        "torch_threads": th.get_num_threads(),
        "torch": th.__version__,
        "python": platform.python_version(),
        "device": device,
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
        "command": "sb3-pola bench " + " ".join(sys.argv[2:] if sys.argv[1:2] == ["bench"] else sys.argv[1:]),
    }
    gpu = gpu_name(device)
    if gpu is not None:
        info["gpu"] = gpu
    return info


def _fmt(value: float, unit: str = "") -> str:
    for scale, prefix in ((1e12, "T"), (1e9, "G"), (1e6, "M"), (1e3, "k")):
        if abs(value) >= scale:
            return f"{value / scale:.2f} {prefix}{unit}"
    return f"{value:.3g} {unit}".rstrip()


def _ms(seconds: float) -> str:
    return f"{seconds * 1e3:.3g} ms"


def _status(met: bool | None) -> str:
    return "" if met is None else ("met" if met else "MISSED")


def _flatten(value: Any, prefix: str = "") -> list[tuple[str, str]]:
    """``(dotted key, rounded value)`` of every leaf of nested dicts and lists."""
    if isinstance(value, dict):
        return [item for k, v in value.items() for item in _flatten(v, f"{prefix}.{k}" if prefix else str(k))]
    if isinstance(value, list):
        return [item for i, v in enumerate(value) for item in _flatten(v, f"{prefix}[{i}]")]
    if isinstance(value, float):
        return [(prefix, f"{value:.4g}")]
    return [(prefix, str(value))]


def _seconds(value: Any) -> str:
    return f"{value:.3g} s" if isinstance(value, (int, float)) else ""


def _other_section(name: str, section: Any) -> list[str]:
    """A section the tables do not know (an error, an older layout) as a dotted key list."""
    lines = ["", f"{name} (from `sb3_pola.benchmarks.{name}_bench`):", ""]
    return lines + [f"- {key}: {value}" for key, value in _flatten(section)]


def _export_table(export: Any) -> list[str]:
    """Single-observation latency of the exported policy (``export_bench.run``'s result)."""
    if export is None:
        return []
    if not isinstance(export, dict) or "configs" not in export:
        return _other_section("export", export)
    from sb3_pola.benchmarks.export_bench import format_table

    return format_table(export)


def _data_table(data: Any) -> list[str]:
    """Dataset load times and memory, one row per dataset (``data_bench.run``'s ``{dataset id: figures}``)."""
    if data is None:
        return []
    rows = {k: v for k, v in data.items() if isinstance(v, dict) and "steps" in v} if isinstance(data, dict) else {}
    if not rows:
        return _other_section("data", data)
    lines = [
        "",
        "| dataset | steps | first load | cached load | float32 size | peak memory / float32 (first, cached load) "
        "| buffer shares memory |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        first_peak, cached_peak = r.get("tracemalloc_peak_build_over_float32"), r.get("tracemalloc_peak_cached_over_float32")
        peak = f"{first_peak:.3f}x, {cached_peak:.3f}x" if first_peak is not None and cached_peak is not None else ""
        shares = r.get("buffer_shares_memory")
        lines.append(
            f"| {name} | {r['steps']:,} | {_seconds(r.get('first_load_s'))} | {_seconds(r.get('cached_load_s'))} | "
            f"{r.get('float32_mb', '')} MB | {peak} | {'' if shares is None else ('yes' if shares else 'NO')} |"
        )
    extra = [
        f"peak RSS of the benchmark process so far {v:.0f} MB" if k == "process_maxrss_mb" else f"{k}: {v}"
        for k, v in data.items()
        if k not in rows
    ]
    lines += [
        "",
        "Load times are wall clock (first: Minari episode by episode into a fresh cache; cached: from that cache); "
        "peak memory is the Python-level (tracemalloc) peak while loading." + (f" {'; '.join(extra)}." if extra else ""),
    ]
    return lines


def _dynamics_table(dyn: Any) -> list[str]:
    """The dynamics model's fit, one row per data size (``dynamics_bench.run``'s ``fit`` list)."""
    if dyn is None:
        return []
    fits = dyn.get("fit") if isinstance(dyn, dict) else None
    if not isinstance(fits, list) or not all(isinstance(m, dict) and "fit_time" in m for m in fits):
        return _other_section("dynamics", dyn)
    lines = [
        "",
        "| dynamics fit, transitions | fit time | epochs | gradient steps | ms/step | holdout next-state MSE "
        "(no-change MSE) | holdout reward MSE |",
        "|---|---|---|---|---|---|---|",
    ]
    for m in fits:
        mse, no_change = m.get("holdout_mse"), m.get("no_change_mse")
        ratio = f", ratio {mse / no_change:.3f}" if mse is not None and no_change else ""
        mse_text = f"{mse:.4g} ({no_change:.4g}{ratio})" if mse is not None and no_change is not None else ""
        reward = m.get("holdout_reward_mse")
        lines.append(
            f"| {int(m['n']):,} | {_seconds(m['fit_time'])} | {int(m.get('epochs', 0))} | {int(m.get('steps', 0))} | "
            f"{m.get('ms_per_step', float('nan')):.3g} | {mse_text} | {'' if reward is None else f'{reward:.3g}'} |"
        )
    notes = ["7 members, 5 elites, 4 x 200, batch 256, epochs capped (an epoch is at most 1000 gradient steps)"]
    step = dyn.get("step")
    if isinstance(step, dict) and "step_deterministic_ms" in step:
        notes.append(
            f"one differentiable step() at batch 256 (forward + backward to the inputs): deterministic "
            f"{step['step_deterministic_ms']:.3g} ms, stochastic {step.get('step_stochastic_ms', float('nan')):.3g} ms"
        )
    if "threads" in dyn:
        load = ""
        if isinstance(dyn.get("load_before"), (int, float)) and isinstance(dyn.get("load_after"), (int, float)):
            load = f", 1-minute load {dyn['load_before']:.2f} -> {dyn['load_after']:.2f}"
        notes.append(f"torch threads {dyn['threads']}{load}")
    return [*lines, "", "; ".join(notes) + "."]


def format_tables(results: dict[str, Any]) -> str:
    """Markdown tables of the results, each figure next to its target where the issue sets one."""
    info = results["machine"]
    lines = [
        f"Machine: {info['cpu']} ({info['cpu_count']} cores, torch threads {info['torch_threads']}), "
        f"device {info['device']}{' ' + info['gpu'] if 'gpu' in info else ''}, torch {info['torch']}; "
        f"{info['date']}; `{info['command']}`",
        "",
    ]
    train = results.get("train")
    if isinstance(train, dict) and "configs" in train:
        lines += [
            "| configuration | obs/act | N | T | products | batch | data | step | steps/s | GFLOP/step | roofline fraction |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in train["configs"]:
            flops = f"{r['flops'] / 1e9:.2f}" if "flops" in r else ""
            roof = (
                f"{r['roofline_fraction']:.2f} (target >= 0.5: {_status(r['roofline_fraction'] >= 0.5)})"
                if "flops" in r
                else ""
            )
            lines.append(
                f"| {r['name']} | {r['obs_dim']}/{r['act_dim']} | {r['n_critics']} | {r['rollout_length']} | "
                f"{'on' if r['use_state_products'] else 'off'} | {r['batch_size']} | {r['n_data'] // 1000}k | {_ms(r['step_s'])} | "  # noqa: E501
                f"{r['steps_per_s']:.2f} | {flops} | {roof} |"
            )
        for r in train["configs"]:
            if "flops" in r:
                lines.append(
                    f"\n{r['name']}: achieved {_fmt(r['achieved_flops_per_s'], 'FLOP/s')}, "
                    f"the same matmuls alone {_fmt(r['matmul_flops_per_s'], 'FLOP/s')} ({_ms(r['matmul_seconds'])} of the step)"  # noqa: E501
                )
        lines += ["", "| scaling check | figure | target | status |", "|---|---|---|---|"]
        scaling = train.get("scaling", {})
        if "linear_in_T" in scaling:
            s = scaling["linear_in_T"]
            pts = ", ".join(f"T={t}: {_ms(v)}" for t, v in s["points"])
            lines.append(
                f"| step time linear in T | {pts}; +{_ms(s['slope_s_per_T'])}/T, max residual {s['max_rel_residual']:.1%} | {s['target']} | {_status(s['met'])} |"  # noqa: E501
            )
        if "n10_over_n2" in scaling:
            s = scaling["n10_over_n2"]
            lines.append(f"| N=10 / N=2 step time | {s['ratio']:.2f}x | {s['target']} | {_status(s['met'])} |")
        if "dataset_1m_over_100k" in scaling:
            s = scaling["dataset_1m_over_100k"]
            lines.append(f"| 1M / 100k transitions step time | {s['ratio']:.2f}x | {s['target']} | {_status(s['met'])} |")
        if "gpu_paper_steps_per_s" in scaling:
            s = scaling["gpu_paper_steps_per_s"]
            lines.append(
                f"| GPU: paper configuration | {s['steps_per_s']:.0f} steps/s ({s['best']}) | {s['target']} "
                f"| {_status(s['met'])} |"
            )
        elif info["device"] == "cpu":
            lines.append("| GPU: paper configuration | not measured (CPU run; `--device cuda` on a GPU) | >= 500 steps/s | |")
    pred = results.get("predict")
    if isinstance(pred, dict) and "single" in pred:
        s = pred["single"]
        rule = f" ({s['rule']} rule)" if "rule" in s else ""  # JSON written before the rule was recorded has none
        lines += [
            "",
            "| predict | POLA | SB3 SAC | target | status |",
            "|---|---|---|---|---|",
            f"| one observation{rule}, median of {s['n_calls']} | {_ms(s['pola_median_s'])} ({s['ratio']:.2f}x SAC) "
            f"| {_ms(s['sac_median_s'])} | <= 2x SAC | {_status(s['met'])} |",
            f"| one observation, p99 | {_ms(s['pola_p99_s'])} | {_ms(s['sac_p99_s'])} | | |",
        ]
        if "one_sample_median_s" in s:  # the one-chain rule, timed beside the policy's own
            lines.append(
                f"| one observation (observation_noise rule), median | {_ms(s['one_sample_median_s'])} "
                f"({s['one_sample_median_s'] / s['sac_median_s']:.2f}x SAC) | | | |"
            )
        for variant, b in pred["batched"].items():
            lines.append(
                f"| batch of {b['batch']}, {variant} | {_ms(b['seconds'])}, {_fmt(b['obs_per_s'], 'obs/s')}; roofline fraction "  # noqa: E501
                f"{b['roofline_fraction']:.2f} ({_fmt(b['achieved_flops_per_s'], 'FLOP/s')} vs matmuls alone "
                f"{_fmt(b['matmul_flops_per_s'], 'FLOP/s')}) | | >= 0.5 | {_status(b['roofline_fraction'] >= 0.5)} |"
            )
    elif pred is not None:
        lines += ["", f"predict: {pred}"]
    lines += _export_table(results.get("export"))
    lines += _data_table(results.get("data"))
    lines += _dynamics_table(results.get("dynamics"))
    lines += ["", f"Total benchmark time: {results['total_s']:.0f} s"]
    return "\n".join(lines)


def run_section(name: str, quick: bool, device: str, policy_kwargs: dict[str, Any], compiled: bool) -> Any:
    start = time.perf_counter()
    try:
        if name == "train":
            from sb3_pola.benchmarks import train_bench

            result: Any = train_bench.run(quick, device, policy_kwargs=policy_kwargs, compiled=compiled)
        elif name == "predict":
            from sb3_pola.benchmarks import predict_bench

            result = predict_bench.run(quick, device, policy_kwargs=policy_kwargs, compiled=compiled)
        else:  # the export, data and dynamics benchmarks (their own modules, CPU/GPU as they choose)
            module = importlib.import_module(f"sb3_pola.benchmarks.{name}_bench")
            result = module.run(quick)
    except Exception as error:  # one broken section must not lose the others
        extra = missing_extra("bench", error)
        if extra is None:
            traceback.print_exc()
            result = {"error": f"{type(error).__name__}: {error}"}
        else:  # e.g. the export section without onnxruntime: say which extra, no traceback
            message = missing_extra_message("bench", extra, error)
            print(message, file=sys.stderr)
            result = {"skipped": message}
    print(f"[bench] {name}: {time.perf_counter() - start:.1f} s", flush=True)
    return result


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="sb3-pola bench", description=__doc__)
    parser.add_argument(
        "--quick", action="store_true", help="reduced set (fewer configurations, sizes and repetitions): a smoke check"
    )
    parser.add_argument("--out", default="benchmarks/results", help="folder of the JSON and the README table")
    parser.add_argument("--device", default="auto", help="cpu, cuda or auto (cuda when available)")
    parser.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: all cores)")
    parser.add_argument("--only", nargs="+", choices=SECTIONS, default=list(SECTIONS), help="sections to run")
    parser.add_argument(
        "--compile", choices=("auto", "on", "off"), default="auto", help="also time compiled Mish (auto: full mode only)"
    )
    args = parser.parse_args(argv)
    device = ("cuda" if th.cuda.is_available() else "cpu") if args.device == "auto" else args.device
    threads = args.threads or len(os.sched_getaffinity(0))
    th.set_num_threads(threads)
    compiled = args.compile == "on" or (args.compile == "auto" and not args.quick)
    policy_kwargs: dict[str, Any] = {}

    start = time.perf_counter()
    results: dict[str, Any] = {"machine": machine_info(device), "quick": args.quick, "compiled": compiled}
    for name in args.only:
        results[name] = run_section(name, args.quick, device, policy_kwargs, compiled)
    results["total_s"] = time.perf_counter() - start

    table = format_tables(results)
    print(table)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = f"bench_{device}{'_quick' if args.quick else ''}"
    (out / f"{stem}.json").write_text(json.dumps(results, indent=2, default=str))
    (out / ("README_table.md" if not args.quick else f"{stem}_table.md")).write_text(table + "\n")
    print(f"[bench] wrote {out / (stem + '.json')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
