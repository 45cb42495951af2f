"""The machine a profile report was made on: CPU model, cores, memory, load, package versions.

Imports the standard library and numpy only.
"""
from __future__ import annotations

import os
import platform
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import numpy as np

#: ``/proc/cpuinfo`` keys that name the CPU or board, most specific first (x86, Raspberry Pi, ...).
CPU_KEYS = ("model name", "Model")
#: weaker ``/proc/cpuinfo`` keys, used only when the device tree names no board (e.g. Pi's "BCM2835").
FALLBACK_KEYS = ("Hardware", "cpu model", "Processor")


def cpu_model(cpuinfo: str | Path = "/proc/cpuinfo", device_tree: str | Path = "/proc/device-tree/model") -> str:
    """The CPU's or board's name: ``/proc/cpuinfo``'s ``model name`` (x86) or ``Model`` (Raspberry Pi
    OS), else the device tree's model (Jetson), else the weaker cpuinfo keys, else ``platform``."""
    def read(path) -> str:
        try:
            return Path(path).read_text(encoding="utf-8", errors="replace")
        except OSError:
            return ""
    found: dict[str, str] = {}
    for line in read(cpuinfo).splitlines():
        key, sep, value = line.partition(":")
        key, value = key.strip(), value.strip()
        if sep and value:
            found.setdefault(key, value)
    for key in CPU_KEYS:
        if key in found:
            return found[key]
    board = read(device_tree).strip("\x00 \n")
    if board:
        return board
    for key in FALLBACK_KEYS:
        if key in found:
            return found[key]
    return platform.processor() or platform.machine() or "unknown"


def package_version(distribution: str) -> str | None:
    """Installed version of a distribution, None when it is not installed."""
    try:
        return version(distribution)
    except PackageNotFoundError:
        return None


def memory_gb() -> float | None:
    """Total memory in GB from ``/proc/meminfo`` (None where there is none)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                return round(int(line.split()[1]) / 1024 ** 2, 1)
    except (OSError, ValueError, IndexError):
        pass
    return None


def machine_info() -> dict:
    """CPU model, core counts, memory, load, platform and package versions of this machine."""
    info: dict[str, Any] = {
        "cpu_model": cpu_model(),
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "machine": platform.machine(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": package_version("numba"),
        "opencv": package_version("opencv-python-headless") or package_version("opencv-python"),
        "lite_vo": package_version("lite-vo"),
    }
    try:
        info["cores_available"] = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        info["cores_available"] = os.cpu_count()
    try:
        info["load_avg_1_5_15"] = [round(x, 2) for x in os.getloadavg()]
    except (AttributeError, OSError):
        info["load_avg_1_5_15"] = None
    mem = memory_gb()
    if mem is not None:
        info["memory_gb"] = mem
    return info
