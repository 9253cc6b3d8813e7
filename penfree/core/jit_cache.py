"""Numba's on-disk cache, invalidated by every source a kernel can have inlined.

Numba stamps a cached kernel with a hash of the file that defines it and of the
function's own bytecode, nothing else. A kernel that calls another ``@njit``
function has that function's machine code compiled into it: when only the callee's
file changes (an upgrade, a pull, an edit), Numba still loads the old kernel, and a
fixed distance or orientation predicate would keep running its old code inside the
broad phase. The certificate rests on those predicates, so a stale kernel is a
correctness hazard, not a speed one.

`install` puts one locator in front of Numba's own for the files of a package. It
asks Numba's locators where the cache lives (``__pycache__``, ``NUMBA_CACHE_DIR`` or
the user-wide directory, unchanged) and adds to their stamp a hash of the package
modules the function's module imports, directly or through other package modules:
a kernel can only inline what its module can reach. Any import counts, also inside
functions, so the set is a superset of what can be inlined. Editing `distance.py`
therefore recompiles the broad phase, and editing the fit leaves it cached.
(``NUMBA_CACHE_LOCATOR_CLASSES``, when a user sets it, replaces the whole list and
this locator with it.)
"""

from __future__ import annotations

import functools
import hashlib
import os
import re
from pathlib import Path

from numba.core import caching

#: The class whose ``_locator_classes`` Numba tries in order (``_CacheImpl`` in older Numba).
_CACHE_IMPL = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl")

#: The package directories whose kernels get the dependency stamp.
_ROOTS: list[Path] = []


def _module_name(path: Path, root: Path) -> tuple[str, bool]:
    """``(dotted name, is a package)`` of a file under `root`."""
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    is_pkg = parts[-1] == "__init__"
    return ".".join(parts[:-1] if is_pkg else parts), is_pkg


@functools.lru_cache(maxsize=None)
def _module_file(name: str, root: Path) -> Path | None:
    """The file of module `name` under `root`, or None when it is not a module there."""
    rel = Path(*name.split(".")[1:])  # Path() for the package itself
    if rel.parts and (root / rel).with_suffix(".py").is_file():
        return (root / rel).with_suffix(".py")
    init = root / rel / "__init__.py"
    return init if init.is_file() else None


#: ``from <module> import <names>``, anywhere (after ``try:``, ``;``, inside functions);
#: the names run to the closing parenthesis or the end of the logical line.
_FROM = re.compile(rb"\bfrom[\s\\]+(\.*)([\w.]*)[\s\\]+import[\s\\]*(\([^)]*\)|(?:[^\n;\\]|\\\n)*)")
#: ``import a.b, c as d``, anywhere (a ``from`` import's names match too: harmless).
_IMPORT = re.compile(rb"\bimport[\s\\]+([\w.]+(?:[\s\\]+as[\s\\]+\w+)?(?:[\s\\]*,[\s\\]*[\w.]+(?:[\s\\]+as[\s\\]+\w+)?)*)")
_WORD = re.compile(rb"[\w.]+")


@functools.lru_cache(maxsize=None)
def _parsed(path: str, mtime_ns: int, size: int) -> tuple[bytes, tuple]:
    """``(sha256 of the bytes, its imports)`` of one file, memoised per version of it.

    An import is a dotted name (``import a.b``) or ``(level, module, names)`` (``from``).
    The file is scanned as text, not parsed (parsing the kernels' modules took ~0.2 s
    of every command's start): every import statement matches, and words in
    comments, strings or aliases only add candidates, so the set is a superset.
    """
    data = Path(path).read_bytes()
    names = []
    for m in _FROM.finditer(data):
        names.append((len(m[1]), m[2].decode(), tuple(w.decode() for w in _WORD.findall(m[3]))))
    for m in _IMPORT.finditer(data):
        names += [w.decode() for w in _WORD.findall(m[1])]
    return hashlib.sha256(data).digest(), tuple(names)


def _signature(path: Path) -> tuple[Path, int, int]:
    st = os.stat(path)
    return (path, st.st_mtime_ns, st.st_size)


def _imported_files(path: Path, root: Path) -> tuple[Path, ...]:
    """The files under `root` whose names `path` imports (memoised per version of `path`).

    ``import a.b`` reaches ``a/b``; ``from a import n`` reaches the module ``a.n`` when
    there is one, else ``a`` (where the name ``n`` is defined).
    """
    _, mtime_ns, size = _signature(path)
    return _edges(path, root, mtime_ns, size)


@functools.lru_cache(maxsize=None)
def _edges(path: Path, root: Path, mtime_ns: int, size: int) -> tuple[Path, ...]:
    name, is_pkg = _module_name(path, root)
    package = name if is_pkg else name.rpartition(".")[0]
    targets = []
    for item in _parsed(str(path), mtime_ns, size)[1]:
        if isinstance(item, str):
            targets.append(item)
            continue
        level, module, names = item
        if level:
            base = package.split(".")
            base = base[: len(base) - (level - 1)]
            module = ".".join(base + ([module] if module else []))
        if module.split(".")[0] == root.name:
            targets += [f"{module}.{n}" if _module_file(f"{module}.{n}", root) else module for n in names]
    found = {_module_file(t, root) for t in targets if t.split(".")[0] == root.name}
    return tuple(sorted(f for f in found if f is not None))


def dependency_files(path: Path, root: Path) -> list[Path]:
    """`path` and every file under `root` it imports, directly or transitively, sorted."""
    path, root = Path(path).resolve(), Path(root).resolve()
    seen, todo = {path}, [path]
    while todo:
        for dep in _imported_files(todo.pop(), root):
            if dep not in seen:
                seen.add(dep)
                todo.append(dep)
    return sorted(seen)


#: (file, root) -> (each dependency's (path, mtime_ns, size), stamp): the kernels of one
#: module are decorated one after another and share their module's stamp.
_STAMPS: dict[tuple[str, str], tuple[tuple, str]] = {}


def source_stamp(path: Path, root: Path) -> str:
    """A hash of the contents (and package paths) of `dependency_files(path, root)`."""
    key = (str(path), str(root))
    known = _STAMPS.get(key)
    if known is not None and all(_signature(sig[0]) == sig for sig in known[0]):
        return known[1]
    root = Path(root).resolve()
    # One stat per file: the memo records the versions whose contents were hashed.
    sigs = tuple(_signature(dep) for dep in dependency_files(path, root))
    h = hashlib.sha256()
    for dep, mtime_ns, size in sigs:
        h.update(dep.relative_to(root).as_posix().encode() + b"\0" + _parsed(str(dep), mtime_ns, size)[0])
    _STAMPS[key] = (sigs, h.hexdigest())
    return _STAMPS[key][1]


@functools.lru_cache(maxsize=None)
def _root_of(py_file: str) -> Path | None:
    try:
        path = Path(py_file).resolve()
    except OSError:
        return None
    return next((r for r in _ROOTS if path.is_relative_to(r)), None)


class DependencyStampLocator(caching._CacheLocator):
    """Numba's own locator for the function, with the dependency hash added to its stamp."""

    def __init__(self, inner, stamp):
        self._inner = inner
        self._stamp = stamp
        # Numba's warning about a kernel it cannot cache (dynamic globals) names this file.
        self._py_file = getattr(inner, "_py_file", None)

    def ensure_cache_path(self):
        self._inner.ensure_cache_path()

    def get_cache_path(self):
        return self._inner.get_cache_path()

    def get_source_stamp(self):
        return (self._inner.get_source_stamp(), self._stamp)

    def get_disambiguator(self):
        return self._inner.get_disambiguator()

    @classmethod
    def from_function(cls, py_func, py_file):
        root = _root_of(py_file)
        if root is None:
            return None
        for other in _CACHE_IMPL._locator_classes:
            if other is cls:
                continue
            inner = other.from_function(py_func, py_file)
            if inner is not None:
                return cls(inner, source_stamp(Path(py_file), root))
        return None


def install(package_dir: Path) -> None:
    """Stamp the cached kernels of the package at `package_dir` with their dependencies.

    Idempotent. Must run before the package's ``cache=True`` functions are decorated
    (Numba picks the locator and reads the stamp at decoration).
    """
    root = Path(package_dir).resolve()
    if root not in _ROOTS:
        _ROOTS.append(root)
        _root_of.cache_clear()
    if DependencyStampLocator not in _CACHE_IMPL._locator_classes:
        _CACHE_IMPL._locator_classes.insert(0, DependencyStampLocator)
