"""JIT warm-up: compile (and cache on disk) every numba kernel of the project once.

Owns :data:`KERNEL_MODULES` (the kernel modules, each exposing ``warmup() -> None`` that calls
its kernels once on tiny inputs) and :func:`warmup`, which imports each module, calls its
``warmup()`` and reports the time per module. Modules that do not exist (not written yet, or an
optional extra not installed) are skipped with a note rather than failing.

With ``cache=True`` kernels, the first process on a machine pays the compilation (seconds per
kernel, worse on an ARM board); later processes load the machine code from numba's cache
(``__pycache__`` beside the sources, or ``NUMBA_CACHE_DIR``). The cache is tied to the CPU
model, so run ``lite-vo warmup`` once on the target board after installing.

Plug-ins (e.g. the AR demo) contribute their kernel modules through the entry-point group
``lite_vo.kernels`` (name = anything, value = a module with ``warmup()``), so the core names none
of them; a plug-in module whose optional dependencies are missing is skipped with a note.

Imports: the standard library only at module level. The kernel modules are imported by name
(``importlib``) when :func:`warmup` runs.
"""
from __future__ import annotations

import importlib
import inspect
import time
from dataclasses import asdict, dataclass
from importlib.metadata import entry_points
from typing import Callable, Iterable

#: The kernels every run needs (loaded before a run's clock starts).
CORE_KERNEL_MODULES: tuple[str, ...] = ("lite_vo.image", "lite_vo.tracking._kernels", "lite_vo.mapping._kernels")

#: The core's kernel modules in warm-up order; each exposes ``warmup() -> None``.
KERNEL_MODULES: tuple[str, ...] = CORE_KERNEL_MODULES + ("lite_vo.synth._kernels", "lite_vo._cloud_kernels")

#: Entry-point group through which plug-ins register kernel modules.
KERNEL_ENTRY_POINTS = "lite_vo.kernels"


def plugin_kernel_modules() -> tuple[str, ...]:
    """Kernel modules registered by installed plug-ins (entry points ``lite_vo.kernels``)."""
    return tuple(sorted(ep.value for ep in entry_points(group=KERNEL_ENTRY_POINTS)))


def all_kernel_modules() -> tuple[str, ...]:
    """The core's kernel modules followed by the plug-ins'."""
    return KERNEL_MODULES + tuple(m for m in plugin_kernel_modules() if m not in KERNEL_MODULES)


@dataclass(frozen=True)
class ModuleWarmup:
    """Outcome of warming up one module.

    ``status``: ``"ok"`` (warm-up ran), ``"missing"`` (module not found, skipped),
    ``"no_warmup"`` (module has no ``warmup()``), ``"error"`` (import or warm-up raised).
    ``import_s`` and ``compile_s`` are wall-clock seconds (``compile_s`` is the ``warmup()`` call:
    compilation on a cold cache, loading from the cache on a warm one).
    """
    module: str
    status: str
    import_s: float = 0.0
    compile_s: float = 0.0
    message: str = ""

    @property
    def total_s(self) -> float:
        return self.import_s + self.compile_s

    def to_dict(self) -> dict:
        return asdict(self) | {"total_s": self.total_s}


def _is_missing(err: ModuleNotFoundError, module: str) -> bool:
    """True when ``err`` says ``module`` itself (or one of its parent packages) does not exist."""
    if err.name is None:
        return False
    return module == err.name or module.startswith(err.name + ".")


def warmup_module(module: str, runtime: bool = False) -> ModuleWarmup:
    """Import ``module`` and call its ``warmup()``; never raises for a missing or broken module.

    ``runtime``: ask the module for the kernels a run uses only (``warmup(runtime=True)``, where its
    ``warmup`` takes that argument): every kernel loaded into a process costs memory (about 0.5-2 MB
    each), and the tests and tools use signatures a run never needs."""
    t0 = time.perf_counter()
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as err:
        if _is_missing(err, module):
            return ModuleWarmup(module, "missing", message="module not found (skipped)")
        if module in plugin_kernel_modules():  # a plug-in whose optional dependency is not installed
            return ModuleWarmup(module, "missing",
                                message=f"optional dependency {err.name!r} not installed (skipped)")
        return ModuleWarmup(module, "error", time.perf_counter() - t0,
                            message=f"import failed: {type(err).__name__}: {err}")
    except Exception as err:  # noqa: BLE001 - reported, the other modules still warm up
        return ModuleWarmup(module, "error", time.perf_counter() - t0,
                            message=f"import failed: {type(err).__name__}: {err}")
    import_s = time.perf_counter() - t0
    fn = getattr(mod, "warmup", None)
    if not callable(fn):
        return ModuleWarmup(module, "no_warmup", import_s, message="module has no warmup() (skipped)")
    t1 = time.perf_counter()
    try:
        if runtime and "runtime" in inspect.signature(fn).parameters:
            fn(runtime=True)
        else:
            fn()
    except Exception as err:  # noqa: BLE001
        return ModuleWarmup(module, "error", import_s, time.perf_counter() - t1,
                            message=f"warmup() failed: {type(err).__name__}: {err}")
    return ModuleWarmup(module, "ok", import_s, time.perf_counter() - t1)


def warmup(modules: Iterable[str] | None = None,
           on_result: Callable[[ModuleWarmup], None] | None = None, runtime: bool = False) -> list[ModuleWarmup]:
    """Warm up every module in ``modules`` (default: the core's and the plug-ins' kernel modules), in order.

    ``on_result`` is called after each module (e.g. to print progress). ``runtime``: only what a run
    uses (see :func:`warmup_module`; ``lite-vo warmup`` compiles everything). Returns one
    :class:`ModuleWarmup` per module; check ``status == "error"`` for failures.
    """
    results = []
    for module in (all_kernel_modules() if modules is None else modules):
        res = warmup_module(module, runtime)
        results.append(res)
        if on_result is not None:
            on_result(res)
    return results


def numba_cache_location() -> str:
    """Where numba writes its cache: ``NUMBA_CACHE_DIR`` or ``__pycache__`` beside the sources."""
    import os
    return os.environ.get("NUMBA_CACHE_DIR") or "__pycache__ folders beside the kernel sources"
