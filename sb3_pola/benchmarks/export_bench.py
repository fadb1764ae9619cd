"""Export benchmark: single-observation latency of the exported policy next to ``model.predict`` and SB3 SAC's.

The ONNX file under ONNX Runtime and the TorchScript file under ``torch.jit.load``
(:meth:`~sb3_pola.pola.pola.POLA.export_policy`), POLA's own ``predict(obs, deterministic=True)`` and
SB3 SAC's (default ``MlpPolicy``, same observation and action sizes), all timed in one loop of
alternating blocks of calls so the ratios hold on a loaded machine. ONNX Runtime runs with as many intra-op threads as torch.

``python -m sb3_pola.benchmarks.export_bench [--quick] [--threads 1]``.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import tempfile
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th

from sb3_pola.benchmarks.common import TASK_SIZES, make_pola
from sb3_pola.benchmarks.predict_bench import _SpacesEnv
from sb3_pola.common.datasets import synthetic_dataset

# policy_kwargs of the configurations timed: the paper's actor (3 x 256, products on) and the light CPU one's
EXPORT_CONFIGS: dict[str, dict[str, Any]] = {"paper": {}, "light": {"net_arch": [128, 128]}}


def onnx_session(path: str | pathlib.Path, threads: int | None = None) -> Any:
    """An ONNX Runtime CPU session on ``path`` with ``threads`` intra-op threads (default: torch's)."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads or th.get_num_threads()
    options.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def block_interleaved_latency(predicts: list[Any], obs: np.ndarray, n_calls: int, block: int = 50) -> list[dict[str, float]]:
    """Median and p99 latency (seconds) of each predict function, timed in alternating blocks of ``block`` calls.

    Alternating call by call (:func:`~sb3_pola.benchmarks.predict_bench.interleaved_latency`) made
    ``model.predict`` several times slower between ONNX Runtime or TorchScript calls than on its own
    (each runtime evicts the other's working set); blocks keep each one warm, and alternating the blocks
    still spreads a drifting load over all of them.
    """
    for predict in predicts:
        for _ in range(20):
            predict(obs)
    times: list[list[float]] = [[] for _ in predicts]
    while len(times[0]) < n_calls:
        for j, predict in enumerate(predicts):
            for _ in range(min(block, n_calls - len(times[j]))):
                start = time.perf_counter()
                predict(obs)
                times[j].append(time.perf_counter() - start)
    return [{"median_s": float(np.median(t)), "p99_s": float(np.quantile(t, 0.99))} for t in times]


def run(
    quick: bool = False,
    task: str = "hopper",
    configs: dict[str, dict[str, Any]] | None = None,
    n_calls: int | None = None,
) -> dict[str, Any]:
    """Median and p99 single-observation latency of every runtime, and the ratios to SAC and to ``predict``.

    :param quick: fewer calls and the paper configuration only
    :param task: observation and action sizes (:data:`~sb3_pola.benchmarks.common.TASK_SIZES`)
    :param configs: ``{name: policy_kwargs}`` (default :data:`EXPORT_CONFIGS`)
    :param n_calls: timed calls per runtime (default 300 quick, 1000 full)
    :return: ``{"task", "n_calls", "sac": figures, "configs": {name: {runtime: figures, ratios}}}``
    """
    from stable_baselines3 import SAC

    if configs is None:
        configs = {"paper": EXPORT_CONFIGS["paper"]} if quick else EXPORT_CONFIGS
    n_calls = n_calls or (300 if quick else 1000)
    obs_dim, act_dim, env_id = TASK_SIZES[task]
    data = synthetic_dataset(2_000, obs_dim, act_dim, env_id)
    sac = SAC("MlpPolicy", _SpacesEnv(data.observation_space, data.action_space), device="cpu", seed=0)
    obs = data.observations[0]
    names = ["sac"]
    predicts: list[Callable[[np.ndarray], Any]] = [lambda o: sac.predict(o, deterministic=True)]
    with tempfile.TemporaryDirectory() as folder:
        for name, policy_kwargs in configs.items():
            model = make_pola(data, device="cpu", policy_kwargs=policy_kwargs)
            session = onnx_session(model.export_policy(pathlib.Path(folder, f"{name}.onnx")))
            scripted = th.jit.load(str(model.export_policy(pathlib.Path(folder, f"{name}.pt"), format="torchscript")))

            def run_onnx(o: np.ndarray, session: Any = session) -> Any:
                return session.run(None, {"obs": o[None]})[0][0]

            def run_torchscript(o: np.ndarray, scripted: Any = scripted) -> Any:
                with th.no_grad():
                    return scripted(th.as_tensor(o[None])).numpy()[0]

            def run_predict(o: np.ndarray, model: Any = model) -> Any:
                return model.predict(o, deterministic=True)

            names += [f"{name}/onnxruntime", f"{name}/torchscript", f"{name}/predict"]
            predicts += [run_onnx, run_torchscript, run_predict]
        figures = dict(zip(names, block_interleaved_latency(predicts, obs, n_calls), strict=True))
    sac_median = figures["sac"]["median_s"]
    results: dict[str, Any] = {}
    for name in configs:
        rows = {runtime: figures[f"{name}/{runtime}"] for runtime in ("onnxruntime", "torchscript", "predict")}
        predict_median = rows["predict"]["median_s"]
        for row in rows.values():
            row["over_sac"] = row["median_s"] / sac_median
            row["over_predict"] = row["median_s"] / predict_median
        results[name] = rows
    return {
        "task": task,
        "obs_dim": obs_dim,
        "act_dim": act_dim,
        "n_calls": n_calls,
        "threads": th.get_num_threads(),
        "sac": figures["sac"],
        "configs": results,
    }


def format_table(result: dict[str, Any]) -> list[str]:
    """Markdown rows of :func:`run`'s result, one per configuration and runtime."""
    lines = [
        "",
        f"| single observation ({result['task']}, {result['obs_dim']}/{result['act_dim']}), median of {result['n_calls']} "
        "| median | p99 | / SAC predict | / POLA predict |",
        "|---|---|---|---|---|",
    ]
    for name, rows in result["configs"].items():
        for runtime, label in (("onnxruntime", "ONNX Runtime"), ("torchscript", "TorchScript"), ("predict", "model.predict")):
            r = rows[runtime]
            lines.append(
                f"| {name}: {label} | {r['median_s'] * 1e3:.3g} ms | {r['p99_s'] * 1e3:.3g} ms | {r['over_sac']:.2f}x "
                f"| {r['over_predict']:.2f}x |"
            )
    sac = result["sac"]
    lines.append(f"| SB3 SAC predict | {sac['median_s'] * 1e3:.3g} ms | {sac['p99_s'] * 1e3:.3g} ms | 1.00x | |")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="300 calls, the paper configuration only")
    parser.add_argument("--threads", type=int, default=1, help="torch and ONNX Runtime intra-op threads")
    parser.add_argument("--task", choices=sorted(TASK_SIZES), default="hopper")
    args = parser.parse_args(argv)
    th.set_num_threads(args.threads)
    result = run(args.quick, args.task)
    print(json.dumps(result, indent=2))
    print("\n".join(format_table(result)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
