"""Numba's on-disk cache must not serve a kernel whose inlined callee changed.

The oracle of `dependency_files` is the import graph of tests/test_architecture.py
(its own walk of every import); the end-to-end tests run a two-module package in
fresh processes, edit the callee's file, and check the caller's result.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from penfree.core import jit_cache
from penfree.core.contact import broad_phase

PKG = Path(jit_cache.__file__).resolve().parents[1]


def _architecture():
    path = Path(__file__).resolve().parents[1] / "test_architecture.py"
    spec = importlib.util.spec_from_file_location("_architecture_graph", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _reachable(graph, modules, start):
    seen, todo = {start}, [start]
    while todo:
        for target, _, _ in graph[todo.pop()]:
            if target in modules and target not in seen:
                seen.add(target)
                todo.append(target)
    return seen


def test_dependency_files_hold_the_import_graphs_closure():
    # The scan reads text: words in docstrings may add files, never drop one.
    arch = _architecture()
    by_file = {path.resolve(): name for name, (path, _) in arch.MODULES.items()}
    for name, (path, _) in arch.MODULES.items():
        got = {by_file[f] for f in jit_cache.dependency_files(path, PKG)}
        missing = _reachable(arch.GRAPH, arch.MODULES, name) - got
        assert not missing, f"{name}: {sorted(missing)}"


def test_the_broad_phase_depends_on_the_distance_kernels_and_the_fit_does_not():
    deps = {f.relative_to(PKG).as_posix() for f in jit_cache.dependency_files(Path(broad_phase.__file__), PKG)}
    assert {"core/contact/distance.py", "core/contact/orient.py"} <= deps
    fit = {f.relative_to(PKG).as_posix() for f in jit_cache.dependency_files(PKG / "core/fit/kernels.py", PKG)}
    assert not any(f.startswith("core/contact/") for f in fit)


def _write_package(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))
        compile(path.read_text(), str(path), "exec")  # the scan is tested on real Python
    return root


def test_every_form_of_import_is_found(tmp_path):
    pk = _write_package(tmp_path / "pk", {
        "__init__.py": "",
        "a.py": """
            from . import c
            import pk.d.e as q, pk.m
            try: from pk.n import (
                    x,
                    o,
                )
            except ImportError: pass
            y = 1; from .p import z
            from \\
                .r import w
            def f():
                from .b import g
                return g()
        """,
        "b.py": "from .sub import h\n",
        "c.py": "",
        "d/__init__.py": "",
        "d/e.py": "",
        "m.py": "",
        "n/__init__.py": "x = 1\n",
        "n/o.py": "",
        "p.py": "z = 1\n",
        "r.py": "w = 1\n",
        "sub/__init__.py": "def h(): pass\n",
        "unrelated.py": "",
    })
    got = {f.relative_to(pk).as_posix() for f in jit_cache.dependency_files(pk / "a.py", pk)}
    # `from .sub import h` reaches sub/__init__ (h is defined there), `import pk.d.e`
    # only d/e (nothing in d/__init__ is named); `from pk.n import x, o` both n and n/o.
    assert got == {"a.py", "b.py", "c.py", "d/e.py", "m.py", "n/__init__.py", "n/o.py", "p.py", "r.py",
                   "sub/__init__.py"}


def test_the_stamp_follows_contents_not_location(tmp_path):
    copy = tmp_path / "penfree"
    shutil.copytree(PKG, copy, ignore=shutil.ignore_patterns("__pycache__"))
    bp = "core/contact/broad_phase.py"
    before = jit_cache.source_stamp(PKG / bp, PKG)
    assert jit_cache.source_stamp(copy / bp, copy) == before
    with open(copy / "core/fit/kernels.py", "a") as f:
        f.write("\n# an edit the broad phase cannot see\n")
    assert jit_cache.source_stamp(copy / bp, copy) == before
    with open(copy / "core/contact/distance.py", "a") as f:
        f.write("\n# an edit of a kernel the broad phase inlines\n")
    assert jit_cache.source_stamp(copy / bp, copy) != before


def test_penfree_kernels_carry_the_dependency_stamp():
    locator = broad_phase._hit_rate._cache._impl.locator
    assert isinstance(locator, jit_cache.DependencyStampLocator)
    _, stamp = locator.get_source_stamp()
    assert stamp == jit_cache.source_stamp(Path(broad_phase.__file__), PKG)


_RUN = """
import json, sys
from pathlib import Path
from penfree.core import jit_cache
jit_cache.install(Path(sys.argv[1]) / "pk")
import pk.a
value = pk.a.f()
print(json.dumps({"value": value, "hits": sum(pk.a.f.stats.cache_hits.values())}))
"""


def _process(root: Path, cache_dir: Path | None) -> subprocess.CompletedProcess:
    """One fresh process: install the locator for `root/pk`, call ``pk.a.f``."""
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "NUMBA_DISABLE_JIT")}
    env["PYTHONPATH"] = os.pathsep.join([str(root), str(PKG.parent)])
    if cache_dir is not None:
        env["NUMBA_CACHE_DIR"] = str(cache_dir)
    return subprocess.run([sys.executable, "-c", _RUN, str(root)], capture_output=True, text=True, cwd=root, env=env)


def _run(root: Path, cache_dir: Path | None) -> dict:
    """`_process`'s printed value and cache hits (it must succeed)."""
    out = _process(root, cache_dir)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("cache_dir", ["in-tree", "NUMBA_CACHE_DIR"])
def test_a_kernel_recompiles_when_a_function_it_inlined_changes(tmp_path, cache_dir):
    user_dir = tmp_path / "numba-cache" if cache_dir == "NUMBA_CACHE_DIR" else None
    root = tmp_path / "src"
    _write_package(root / "pk", {
        "__init__.py": "",
        "b.py": """
            from numba import njit
            @njit(cache=True)
            def g():
                return 1
        """,
        "a.py": """
            from numba import njit
            from pk.b import g
            @njit(cache=True)
            def f():
                return g() + 10
        """,
        "c.py": "",
    })
    assert _run(root, user_dir) == {"value": 11, "hits": 0}
    assert _run(root, user_dir) == {"value": 11, "hits": 1}          # cached
    (root / "pk/c.py").write_text("# not imported by a\n")
    assert _run(root, user_dir) == {"value": 11, "hits": 1}          # still cached
    (root / "pk/b.py").write_text((root / "pk/b.py").read_text().replace("return 1", "return 2"))
    assert _run(root, user_dir) == {"value": 12, "hits": 0}          # Numba alone would print 11
    assert _run(root, user_dir) == {"value": 12, "hits": 1}
    # The cache stays where Numba would put it.
    where = user_dir if user_dir is not None else root / "pk"
    assert list(where.rglob("a.f-*.nbi"))
    if user_dir is not None:
        assert not list(root.rglob("*.nbi"))


def test_a_kernel_that_cannot_be_cached_warns_and_runs(tmp_path):
    # A kernel with a dynamic global (Numba's thread count read inside it) cannot be
    # cached: Numba warns, naming the file, through the locator, and runs it uncached.
    root = tmp_path / "src"
    _write_package(root / "pk", {
        "__init__.py": "",
        "a.py": """
            import numba
            from numba import njit
            @njit(cache=True)
            def f():
                return 0 * numba.get_num_threads() + 7
        """,
    })
    out = _process(root, None)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1]) == {"value": 7, "hits": 0}
    assert "Cannot cache compiled function" in out.stderr and "a.py" in out.stderr
