"""``sb3-pola bench``: POLA's speed and memory benchmarks, printed as a table next to their targets and saved as JSON.

Sections: gradient steps per second over configurations with FLOPs and roofline fraction
(:mod:`~sb3_pola.benchmarks.train_bench`), predict latency and throughput (:mod:`~sb3_pola.benchmarks.predict_bench`),
dataset load time and memory (:mod:`~sb3_pola.benchmarks.data_bench`) and the dynamics model's fit time
(:mod:`~sb3_pola.benchmarks.dynamics_bench`). Timings are medians after warm-up. ``--quick`` runs a
reduced set in under 2 minutes on 2 CPU cores. Runs unchanged on CUDA (``--device cuda``).
"""

from __future__ import annotations

import argparse
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

SECTIONS = ("train", "predict", "data", "dynamics")


def machine_info(device: str) -> dict[str, Any]:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as file:
            cpu = next(line.split(":", 1)[1].strip() for line in file if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    info: dict[str, Any] = {
        "cpu": cpu,
        "cpu_count": os.cpu_count(),
        "torch_threads": th.get_num_threads(),
        "torch": th.__version__,
        "python": platform.python_version(),
        "device": device,
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
        "command": "sb3-pola bench " + " ".join(sys.argv[2:] if sys.argv[1:2] == ["bench"] else sys.argv[1:]),
    }
    if th.device(device).type == "cuda":
        info["gpu"] = th.cuda.get_device_name()
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
    pred = results.get("predict")
    if isinstance(pred, dict) and "single" in pred:
        s = pred["single"]
        lines += [
            "",
            "| predict | POLA | SB3 SAC | target | status |",
            "|---|---|---|---|---|",
            f"| one observation, median of {s['n_calls']} | {_ms(s['pola_median_s'])} ({s['ratio']:.2f}x SAC) "
            f"| {_ms(s['sac_median_s'])} | <= 2x SAC | {_status(s['met'])} |",
            f"| one observation, p99 | {_ms(s['pola_p99_s'])} | {_ms(s['sac_p99_s'])} | | |",
        ]
        for variant, b in pred["batched"].items():
            lines.append(
                f"| batch of {b['batch']}, {variant} | {_ms(b['seconds'])}, {_fmt(b['obs_per_s'], 'obs/s')}; roofline fraction "  # noqa: E501
                f"{b['roofline_fraction']:.2f} ({_fmt(b['achieved_flops_per_s'], 'FLOP/s')} vs matmuls alone "
                f"{_fmt(b['matmul_flops_per_s'], 'FLOP/s')}) | | >= 0.5 | {_status(b['roofline_fraction'] >= 0.5)} |"
            )
    elif pred is not None:
        lines += ["", f"predict: {pred}"]
    for name in ("data", "dynamics"):
        section = results.get(name)
        if section is not None:
            lines += ["", f"{name} (from `sb3_pola.benchmarks.{name}_bench`):", ""]
            lines += [f"- {key}: {value}" for key, value in _flatten(section)]
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
        else:  # the data and dynamics benchmarks (their own modules, CPU/GPU as they choose)
            module = importlib.import_module(f"sb3_pola.benchmarks.{name}_bench")
            result = module.run(quick)
    except Exception as error:  # one broken section must not lose the others
        traceback.print_exc()
        result = {"error": f"{type(error).__name__}: {error}"}
    print(f"[bench] {name}: {time.perf_counter() - start:.1f} s", flush=True)
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="sb3-pola bench", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="reduced set, under 2 minutes on 2 CPU cores")
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
