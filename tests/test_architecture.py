"""The library's layout rules, checked on its source (``python -m pytest tests/test_architecture.py``):

- no import cycle between the library's modules (imports inside functions count too);
- no private name (``_x``) crosses a module boundary, except between modules of the private kernels
  package ``rgbd_envmap._kernels``;
- each kernels module that holds a stage's kernels is imported by one public module of the library
  (its API module); the shared helpers of the kernels are imported by kernels modules only;
- the reference package never imports the kernels;
- the library imports neither the simulator (``sim``) nor the apps;
- importing every module of the library changes no global state (environment, warning filters,
  numba's threading layer).
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LIB = ROOT / "rgbd_envmap"
KERNELS = "rgbd_envmap._kernels"
#: kernels modules that hold no stage's kernels: imported by kernels modules (intrinsics, shared
#: helpers) or by any API module that runs a two-thread kernel (parallel).
KERNEL_UTILITIES = {f"{KERNELS}.intrinsics", f"{KERNELS}.parallel", f"{KERNELS}.envmap_common"}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(LIB.rglob("*.py"))}


MODULES = _modules()


def _is_package(name: str) -> bool:
    return MODULES[name].name == "__init__.py"


def _resolve(importer: str, level: int, module: str | None) -> str:
    if level == 0:
        return module or ""
    base = importer.split(".")
    if not _is_package(importer):
        base = base[:-1]
    base = base[: len(base) - (level - 1)]
    return ".".join(base + ([module] if module else []))


def _imports(name: str) -> list[tuple[str, str | None, int]]:
    """(imported module, imported name or None, line) of every import in module ``name``; ``from
    P import m`` where ``P.m`` is a module counts as an import of ``P.m``."""
    tree = ast.parse(MODULES[name].read_text(), str(MODULES[name]))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(alias.name, None, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            mod = _resolve(name, node.level, node.module)
            for alias in node.names:
                sub = f"{mod}.{alias.name}"
                out.append((sub, None, node.lineno) if sub in MODULES else (mod, alias.name, node.lineno))
    return out


def _library_edges() -> dict[str, set[str]]:
    edges: dict[str, set[str]] = defaultdict(set)
    for name in MODULES:
        for mod, _, _ in _imports(name):
            if mod in MODULES and mod != name:
                edges[name].add(mod)
    return edges


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(set(edges) | {w for ws in edges.values() for w in ws}):
        if v not in index:
            visit(v)
    return found


def _in_kernels(name: str) -> bool:
    return name == KERNELS or name.startswith(KERNELS + ".")


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def test_the_checker_finds_a_cycle_and_resolves_relative_imports():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _resolve("rgbd_envmap.envmap.map", 1, "rules") == "rgbd_envmap.envmap.rules"
    assert _resolve("rgbd_envmap.envmap", 2, "geometry") == "rgbd_envmap.geometry"


def test_no_import_cycle():
    assert _cycles(_library_edges()) == []


def test_no_private_name_crosses_a_module_boundary_outside_the_kernels():
    bad = []
    for name in MODULES:
        aliases: dict[str, str] = {}  # local name -> library module it is bound to
        tree = ast.parse(MODULES[name].read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                mod = _resolve(name, node.level, node.module)
                for alias in node.names:
                    sub = f"{mod}.{alias.name}"
                    if sub in MODULES:
                        aliases[alias.asname or alias.name] = sub
                    elif mod in MODULES and mod != name and _private(alias.name):
                        if not (_in_kernels(name) and _in_kernels(mod)):
                            bad.append(f"{name}:{node.lineno} imports {alias.name} from {mod}")
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name in MODULES and alias.asname:
                        aliases[alias.asname] = alias.name
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases
                    and _private(node.attr)):
                mod = aliases[node.value.id]
                if mod != name and not (_in_kernels(name) and _in_kernels(mod)):
                    bad.append(f"{name}:{node.lineno} uses {node.value.id}.{node.attr} of {mod}")
    assert bad == []


def test_each_stage_kernels_module_is_called_from_one_api_module():
    importers: dict[str, set[str]] = defaultdict(set)
    for name, targets in _library_edges().items():
        for t in targets:
            if _in_kernels(t) and t != KERNELS:
                importers[t].add(name)
    kernel_modules = [m for m in MODULES if _in_kernels(m) and m != KERNELS]
    assert kernel_modules, "no kernels package"
    problems = []
    for m in kernel_modules:
        outside = {i for i in importers[m] if not _in_kernels(i)}
        if m in KERNEL_UTILITIES:
            if m != f"{KERNELS}.parallel" and outside:
                problems.append(f"{m} is a kernels helper but is imported by {sorted(outside)}")
        elif len(outside) != 1:
            problems.append(f"{m} is imported by {sorted(outside) or 'no API module'}")
        if any(i.startswith("rgbd_envmap.reference") for i in outside):
            problems.append(f"{m} is imported by the reference package")
    assert problems == []


def test_the_library_imports_neither_the_simulator_nor_the_apps():
    bad = [f"{name}:{line} imports {mod}" for name in MODULES for mod, _, line in _imports(name)
           if mod.split(".")[0] in ("sim", "apps")]
    assert bad == []


def test_the_reference_package_imports_no_kernels():
    bad = [f"{name}:{line} imports {mod}" for name in MODULES if name.startswith("rgbd_envmap.reference")
           for mod, _, line in _imports(name) if _in_kernels(mod)]
    assert bad == []


_PROBE = r"""
import json, os, sys, warnings, importlib
import numba
# Third-party packages set things of their own on import (OpenCV LD_LIBRARY_PATH, numpy and open3d
# warning filters): they are imported first, so that what is compared is the library's own doing.
for name in json.loads(sys.argv[2]):
    try:
        importlib.import_module(name)
    except Exception:
        pass  # an optional package (the library imports it lazily, on use)
before = (dict(os.environ), list(warnings.filters), list(numba.config.THREADING_LAYER_PRIORITY))
for name in json.loads(sys.argv[1]):
    importlib.import_module(name)
after = (dict(os.environ), list(warnings.filters), list(numba.config.THREADING_LAYER_PRIORITY))
changed = [what for what, b, a in zip(("environment", "warning filters", "numba threading layer"), before, after)
           if b != a]
env = sorted(k for k in set(before[0]) | set(after[0]) if before[0].get(k) != after[0].get(k))
print(json.dumps({"changed": changed, "env": env}))
"""


@pytest.mark.slow
def test_importing_the_library_changes_no_global_state():
    names = sorted(MODULES)
    third_party = sorted({mod.split(".")[0] for name in MODULES for mod, _, _ in _imports(name)}
                         - set(sys.stdlib_module_names) - {"rgbd_envmap", "__future__"})
    assert {"numpy", "numba", "cv2"} <= set(third_party)
    out = subprocess.run([sys.executable, "-c", _PROBE, json.dumps(names), json.dumps(third_party)],
                         capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    assert json.loads(out.stdout.strip().splitlines()[-1]) == {"changed": [], "env": []}
