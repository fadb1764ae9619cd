"""What machine a measurement ran on: the CPU's model name, core count and GPU, for ``config.json`` and benchmarks."""

from __future__ import annotations

import os
import platform

import torch as th


def cpu_name() -> str:
    """The CPU's model name (Linux: ``/proc/cpuinfo``), else what :mod:`platform` knows."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as file:
            cpu = next(line.split(":", 1)[1].strip() for line in file if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return cpu


def gpu_name(device: str) -> str | None:
    """The GPU's name when ``device`` is a CUDA device, else ``None``."""
    return th.cuda.get_device_name(0) if device.startswith("cuda") else None


def machine_info(device: str) -> str:
    """One line: ``<CPU>, <n> CPU cores[, <GPU>]``."""
    text = f"{cpu_name()}, {os.cpu_count()} CPU cores"
    gpu = gpu_name(device)
    return text + (f", {gpu}" if gpu else "")
