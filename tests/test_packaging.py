"""Packaging: what ``pip install .`` gives a user, checked as CI would.

* The run-time imports of ``rgbd_envmap``, ``sim`` and ``apps`` are exactly the declared dependencies
  (import names mapped to distributions with :func:`importlib.metadata.packages_distributions`): none
  missing, none declared but unused (torch and kornia are test references only: the ``dev`` extra).
* The built wheel, installed into a scratch venv (``--no-deps``; the project venv's third-party
  packages made visible by a plain path in a ``.pth`` file, which does not run the editable install's
  finder that also lives there), works from a directory outside the source tree: the packaged scenes
  and trajectories load by name and ``rgbd-envmap simulate --record-only`` records a session.

Run as a script (``python tests/test_packaging.py``) to print the import → distribution table.
"""

from __future__ import annotations

import ast
import importlib.machinery
import importlib.metadata as md
import inspect
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import time
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("rgbd_envmap", "sim", "apps")
#: What the build needs from the source tree (everything else, e.g. .venv, runs/, build/, stays out).
_BUILD_INPUTS = ("pyproject.toml", "README.md", *PACKAGES)
_COPY_IGNORE = shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc", "*.egg-info")


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _requirement_name(req: str) -> str:
    return _norm(re.match(r"[A-Za-z0-9._-]+", req).group())


def _third_party_imports() -> dict[str, list[tuple[str, bool]]]:
    """Top-level import name → [(``file:line``, at module level?)] over :data:`PACKAGES`."""
    found: dict[str, list[tuple[str, bool]]] = {}
    for pkg in PACKAGES:
        for path in sorted((REPO / pkg).rglob("*.py")):
            tree = ast.parse(path.read_text(), str(path))
            in_function = {id(n) for f in ast.walk(tree) if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
                           for n in ast.walk(f)}
            for node in ast.walk(tree):
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    top = name.split(".")[0]
                    if top in sys.stdlib_module_names or top in PACKAGES or top == "__future__":
                        continue
                    where = f"{path.relative_to(REPO)}:{node.lineno}"
                    found.setdefault(top, []).append((where, id(node) not in in_function))
    return found


def _distributions_of_imports() -> dict[str, list[str]]:
    """Import name → distributions: :func:`importlib.metadata.packages_distributions`, plus top-level
    extension modules shipped without ``top_level.txt`` (OpenEXR's ``OpenEXR.*.so``), which Python 3.11
    infers only from ``.py`` files (3.12 infers them too)."""
    found = {name: list(dists) for name, dists in md.packages_distributions().items()}
    for dist in md.distributions():
        for f in dist.files or ():
            if len(f.parts) == 1 and any(f.name.endswith(s) for s in importlib.machinery.EXTENSION_SUFFIXES):
                name = inspect.getmodulename(f.name)
                if name and dist.metadata["Name"] not in found.setdefault(name, []):
                    found[name].append(dist.metadata["Name"])
    return found


def dependency_report() -> tuple[list[str], list[str]]:
    """(table lines, problems): each third-party import, its distribution and where it is declared."""
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    runtime = {_requirement_name(r) for r in project["dependencies"]}
    extras = {e: {_requirement_name(r) for r in rs} for e, rs in project.get("optional-dependencies", {}).items()}
    dists_of = _distributions_of_imports()
    lines, problems, used = [], [], set()
    for top, sites in sorted(_third_party_imports().items()):
        dists = sorted({_norm(d) for d in dists_of.get(top, [])})
        used.update(dists)
        in_extras = sorted(e for e, names in extras.items() if names & set(dists))
        where = "dependencies" if runtime & set(dists) else ("extra " + "/".join(in_extras) if in_extras else "UNDECLARED")
        lines.append(f"{top:15s} {','.join(dists) or '?':32s} {where:22s} {sites[0][0]} ({len(sites)} imports)")
        if not dists:
            problems.append(f"{top} (imported at {sites[0][0]}): no installed distribution provides it")
        elif where == "UNDECLARED":
            problems.append(f"{top} (imported at {sites[0][0]}): distribution {dists} is not declared")
        elif not runtime & set(dists):
            eager = [w for w, module_level in sites if module_level]
            if eager:
                problems.append(f"{top}: only in an extra but imported at module level ({eager[0]})")
    unused = sorted(runtime - used)
    lines.append(f"declared in dependencies but never imported: {unused}")
    problems += [f"{name}: declared in dependencies but never imported by {PACKAGES}" for name in unused]
    return lines, problems


def test_runtime_imports_are_exactly_the_declared_dependencies():
    lines, problems = dependency_report()
    assert not problems, "\n".join(problems + ["", *lines])


def test_packaged_data_lives_in_the_sim_package():
    from sim.scene import SCENES_DIR
    from sim.trajectory import TRAJECTORIES_DIR

    assert SCENES_DIR.parent.parent == REPO / "sim" and TRAJECTORIES_DIR.parent.parent == REPO / "sim"
    assert {"office", "empty"} <= {p.stem for p in SCENES_DIR.glob("*.yaml")}
    assert {"orbit", "orbit_inward", "sweep"} <= {p.stem for p in TRAJECTORIES_DIR.glob("*.yaml")}


def _run(cmd: list[str], **kw) -> subprocess.CompletedProcess:
    proc = subprocess.run(cmd, capture_output=True, text=True, **kw)
    assert proc.returncode == 0, f"{cmd} exited {proc.returncode}\nstdout:\n{proc.stdout[-4000:]}\nstderr:\n{proc.stderr[-4000:]}"
    return proc


_CHECK_INSTALLED = """
import json, sys
import apps, rgbd_envmap, sim
from sim.scene import SCENES_DIR, load_scene
from sim.trajectory import TRAJECTORIES_DIR, load_trajectory
scene = load_scene("office")
load_trajectory(scene.default_trajectory)
assert load_scene("my_scene.yaml").name == scene.name  # a user's file, relative to the cwd
print(json.dumps({"files": [rgbd_envmap.__file__, sim.__file__, apps.__file__], "scenes_dir": str(SCENES_DIR),
                  "trajectories_dir": str(TRAJECTORIES_DIR), "scene": scene.name, "objects": len(scene.objects),
                  "trajectories": sorted(p.stem for p in TRAJECTORIES_DIR.glob("*.yaml")), "sys_path": sys.path}))
"""


@pytest.mark.slow
def test_built_wheel_installs_and_runs_outside_the_source_tree(tmp_path):
    t0 = time.perf_counter()
    # Build from a clean copy of the build inputs: an in-tree build would leave build/ in the checkout,
    # and setuptools packs whatever build/lib holds, including modules since moved or removed.
    src = tmp_path / "src"
    src.mkdir()
    for name in _BUILD_INPUTS:
        (shutil.copytree(REPO / name, src / name, ignore=_COPY_IGNORE) if (REPO / name).is_dir()
         else shutil.copy2(REPO / name, src / name))
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "RGBD_ENVMAP_COMPILE_LOCKS")}
    env.update(PIP_DISABLE_PIP_VERSION_CHECK="1", PIP_NO_INPUT="1", NUMBA_CACHE_DIR=str(tmp_path / "numba_cache"))
    wheels = tmp_path / "wheels"
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q",
          "-w", str(wheels), str(src)], env=env, cwd=tmp_path)
    (wheel,) = wheels.glob("rgbd_envmap-*.whl")
    t_build = time.perf_counter() - t0

    # A scratch venv without pip: this pip installs into it (--python), before the .pth exists, so it
    # never sees (nor offers to uninstall) the project's editable install.
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], env=env)
    vpy = venv / "bin" / "python"
    _run([sys.executable, "-m", "pip", "--python", str(vpy), "install", "--no-deps", "--no-index", "--no-compile", "-q",
          str(wheel)], env=env, cwd=tmp_path)
    site = Path(_run([str(vpy), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], env=env).stdout.strip())
    # A plain path line: Python adds the directory to sys.path without processing the .pth files in it
    # (the editable install's finder, which maps rgbd_envmap/sim/apps to the source tree).
    (site / "_project_venv_packages.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    t_install = time.perf_counter() - t0 - t_build

    outside = tmp_path / "elsewhere"
    outside.mkdir()
    shutil.copy2(REPO / "sim" / "data" / "scenes" / "office.yaml", outside / "my_scene.yaml")
    info = json.loads(_run([str(vpy), "-c", _CHECK_INSTALLED], env=env, cwd=outside).stdout.splitlines()[-1])
    for f in info["files"]:
        assert Path(f).resolve().is_relative_to(site.resolve()), f"{f}: imported from outside the scratch venv ({site})"
    assert not any(p and Path(p).resolve() == REPO for p in info["sys_path"])
    assert Path(info["scenes_dir"]).resolve().is_relative_to(site.resolve())
    assert Path(info["trajectories_dir"]).resolve().is_relative_to(site.resolve())
    assert info["objects"] > 0 and {"orbit", "orbit_inward", "sweep"} <= set(info["trajectories"])

    # The console script, as a user would call it: 1 s recorded, no pipeline.
    out = tmp_path / "out"
    t1 = time.perf_counter()
    _run([str(venv / "bin" / "rgbd-envmap"), "simulate", "--record-only", "--duration", "1", "--out", str(out),
          "--scene", "office", "--quiet"], env=env, cwd=outside, timeout=240)
    t_simulate = time.perf_counter() - t1
    session = out / "session"
    assert json.loads((session / "calibration.json").read_text())["format"] == "rgbd-envmap-session"
    summary = json.loads((out / "simulation.json").read_text())
    assert summary["depth_packets"] == 5 and summary["colour_packets"] == 30  # 5 Hz depth, 30 Hz colour
    for kind, ext, n in (("depth", "ply", 5), ("colour", "png", 30)):
        index = [ln for ln in (session / f"{kind}.txt").read_text().splitlines() if not ln.startswith("#")]
        poses = [ln for ln in (session / f"{kind}_poses.txt").read_text().splitlines() if not ln.startswith("#")]
        assert len(index) == len(poses) == n
        assert len(list((session / kind).glob(f"*.{ext}"))) == n
    assert (session / "groundtruth" / "envmap.npz").stat().st_size > 0
    print(f"wheel test: build {t_build:.1f} s, install {t_install:.1f} s, simulate {t_simulate:.1f} s, "
          f"total {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    table, issues = dependency_report()
    print("\n".join(table))
    print("\n".join(issues) if issues else "OK: imports and declared dependencies agree")
    sys.exit(1 if issues else 0)
