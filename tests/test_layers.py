"""The architecture stays as simple as the algorithm (ARCHITECTURE.md): checked on the source.

* no import cycles among the project's modules (imports at any level, also inside functions);
* ``lite_vo`` never imports ``ar_demo``, pybullet, trimesh or moderngl, at any level, nor the viewer
  library (rerun) at module level;
* exactly one module drives frames: only ``lite_vo/session.py`` calls ``.process(...)``;
* no ``_private`` names or modules are imported across packages (folders).
"""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("lite_vo", "ar_demo")
# never imported by the core, at any level
HEAVY = {"ar_demo", "pybullet", "trimesh", "moderngl", "pyrender", "open3d"}
# not even loaded when the core's modules are imported (the viewer imports rerun when it is switched on)
NOT_AT_IMPORT = HEAVY | {"rerun"}


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, for every module of the project's packages."""
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).with_suffix("")
            parts = list(rel.parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _package_of(module: str) -> str:
    """The package (folder) a module lives in."""
    path = MODULES[module]
    return module if path.name == "__init__.py" else module.rpartition(".")[0]


def _imports(module: str):
    """(line, imported module, imported name or None) for every import statement of ``module``."""
    tree = ast.parse(MODULES[module].read_text(), str(MODULES[module]))
    pkg = _package_of(module)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield node.lineno, a.name, None
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")
                base = base[:len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module
            for a in node.names:
                sub = f"{target}.{a.name}"
                if sub in MODULES:            # "from pkg import module"
                    yield node.lineno, sub, None
                else:
                    yield node.lineno, target, a.name


def _graph() -> dict[str, set[str]]:
    g = {m: set() for m in MODULES}
    for m in MODULES:
        for _, target, _ in _imports(m):
            if target in MODULES and target != m:
                g[m].add(target)
    return g


def _cycles(g: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in g[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(10000)
    for v in g:
        if v not in index:
            visit(v)
    return out


def test_the_project_modules_are_found():
    assert {"lite_vo.session", "lite_vo.system", "ar_demo.sink", "ar_demo.cli.ar"} <= set(MODULES)


def test_no_import_cycles():
    assert _cycles(_graph()) == []


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_the_core_never_imports_the_ar_demo_or_gl_physics_viewer_packages():
    bad = [f"{m}:{line} imports {target}" for m in MODULES if m.startswith("lite_vo")
           for line, target, _ in _imports(m) if target.split(".")[0] in HEAVY]
    assert bad == []


def test_importing_every_core_module_loads_no_plugin_or_heavy_package():
    core = sorted(m for m in MODULES if m.startswith("lite_vo") and not m.endswith("__main__"))
    code = ("import importlib, sys\n"
            f"for m in {core!r}:\n    importlib.import_module(m)\n"
            f"bad = sorted(k for k in sys.modules if k.split('.')[0] in {sorted(NOT_AT_IMPORT)!r})\n"
            "print(','.join(bad)); sys.exit(1 if bad else 0)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, f"loaded: {r.stdout.strip()} {r.stderr[-2000:]}"


def _process_calls(path: Path) -> list[int]:
    tree = ast.parse(path.read_text(), str(path))
    return [n.lineno for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute)
            and n.func.attr == "process"]


def test_exactly_one_module_drives_frames():
    # the packages; tools/ may call the engine directly to measure it (e.g. a bare API loop)
    files = [p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")]
    drivers = {str(p.relative_to(ROOT)) for p in files if _process_calls(p)}
    # tools/bench_memory.py measures a bare loop over VisualOdometry.process on purpose (issue 18:
    # the Python API without the session); it drives no run of the program
    assert drivers - {"tools/bench_memory.py"} == {"lite_vo/session.py"}


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_private_names_across_packages(module):
    pkg = _package_of(module)
    bad = []
    for line, target, name in _imports(module):
        if target.split(".")[0] not in PACKAGES:
            continue
        target_pkg = _package_of(target) if target in MODULES else target
        if target_pkg == pkg:
            continue
        private_module = any(part.startswith("_") and not part.startswith("__") for part in target.split("."))
        private_name = name is not None and name.startswith("_") and not name.startswith("__")
        if private_module or private_name:
            bad.append(f"line {line}: {target}{'.' + name if name else ''}")
    assert bad == [], f"{module} imports private names of another package: {bad}"


def test_importing_lite_vo_shortens_openmps_spin_unless_the_user_set_it():
    """GOMP_SPINCOUNT defaults to a short spin (idle OpenMP threads burned CPU the reader needs); a value
    the user set is kept."""
    import os
    import subprocess
    import sys
    code = "import os, lite_vo; print(os.environ.get('GOMP_SPINCOUNT'))"
    env = {k: v for k, v in os.environ.items() if k != "GOMP_SPINCOUNT"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "30000"
    env["GOMP_SPINCOUNT"] = "INFINITY"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "INFINITY"
