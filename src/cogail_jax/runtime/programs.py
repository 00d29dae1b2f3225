"""Programs traced once and kept between runs.

JAX traces a jitted function (runs its Python on abstract values) the first time each process calls it; XLA's
compilation cache then saves only the compilation after that. For the MJX tasks the tracing of the initial state,
BC, the training chunk and the evaluation programs is tens of seconds of every run. ``stored(fn, name, key)`` jits
``fn`` through ``jax.export``: its program, once traced, is written to the program folder (``programs/`` beside the
compilation cache) under a digest of everything it was built from (this package's and ``cogail_envs``' files, the
installed versions, the backend, the caller's ``key`` for what ``fn`` closes over, the arguments' structure and
shapes), and a later process loads it instead of tracing. Every call runs the exported program, whether it was
traced or loaded, so a run's figures do not depend on what the folder held. A function that cannot be exported
runs as plain ``jax.jit``.
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import importlib
import importlib.metadata as md
import os
import pickle
import re
import threading
from pathlib import Path

import jax
import numpy as np

FORMAT = 1  # bump when what a program file holds changes
SUFFIX = ".jaxprog"
PACKAGES = ("cogail_jax", "cogail_envs")  # whose files the programs are traced from
VERSIONS = ("jax", "jaxlib", "flax", "optax", "brax", "mujoco", "mujoco-mjx", "numpy")


@functools.cache
def code_digest() -> str:
    """A digest of every file of ``PACKAGES`` and the installed ``VERSIONS``: what a traced program depends on
    besides its function's arguments and closure."""
    h = hashlib.sha256(f"format {FORMAT}".encode())
    for pkg in PACKAGES:
        root = Path(importlib.import_module(pkg).__file__).parent
        for p in sorted(root.rglob("*")):
            if p.is_file() and "__pycache__" not in p.parts:
                h.update(str(p.relative_to(root)).encode() + b"\0" + p.read_bytes())
    for dist in VERSIONS:
        try:
            h.update(f"{dist}={md.version(dist)};".encode())
        except md.PackageNotFoundError:
            h.update(f"{dist}=-;".encode())
    return h.hexdigest()


def digest(*parts) -> str:
    """A digest of nested values that is the same in every process: strings, numbers, arrays (dtype, shape and
    bytes), dicts, sequences, dataclasses and other objects (by their fields), types (by name) and treedefs (node
    by node, with their static data; ``str(treedef)`` holds object addresses, e.g. of MJX's contact data)."""
    h = hashlib.sha256()

    def add(x):
        if isinstance(x, jax.tree_util.PyTreeDef):
            data = x.node_data()
            add(("leaf",) if data is None else ("node", data[0], data[1], x.children()))
        elif isinstance(x, type):
            h.update(f"type {x.__module__}.{x.__qualname__};".encode())
        elif dataclasses.is_dataclass(x):
            add((type(x), dataclasses.asdict(x)))
        elif isinstance(x, dict):
            h.update(b"{")
            for k in sorted(x, key=str):
                add(k)
                add(x[k])
            h.update(b"}")
        elif isinstance(x, (list, tuple)):
            h.update(f"{type(x).__name__}(".encode())
            for v in x:
                add(v)
            h.update(b")")
        elif isinstance(x, (np.ndarray, jax.Array)):
            a = np.asarray(x)
            h.update(f"array {a.dtype} {a.shape}".encode() + np.ascontiguousarray(a).tobytes())
        elif isinstance(x, (str, bytes, int, float, complex, bool, np.generic, np.dtype)) or x is None:
            h.update(f"{type(x).__name__}:{x!r};".encode())
        elif fields := _fields(x):
            add((type(x), fields))
        else:  # e.g. a function: its name, without the address in its text
            h.update(re.sub(r" at 0x[0-9a-f]+", "", f"{type(x).__name__}:{x!r};").encode())

    add(parts)
    return h.hexdigest()


def _fields(x) -> dict:
    """An object's attributes (``__dict__`` or ``__slots__``), {} for none."""
    if hasattr(x, "__dict__") and not callable(x):
        return dict(vars(x))
    slots = [n for t in type(x).__mro__ for n in getattr(t, "__slots__", ()) if n != "__weakref__"]
    return {n: getattr(x, n) for n in slots if hasattr(x, n)}


def program_dir() -> Path | None:
    """Where programs are kept: ``programs/`` in JAX's compilation cache folder (``xla.enable_compile_cache``), or
    None (programs traced in every process) when no compilation cache is set."""
    cache = jax.config.jax_compilation_cache_dir
    return Path(cache) / "programs" if cache else None


def _context() -> tuple:
    """What a trace reads from JAX's global state."""
    c = jax.config
    return (jax.default_backend(), str(c.jax_default_matmul_precision), bool(c.jax_enable_x64),
            str(c.jax_default_prng_impl))


def _read(path: Path | None):
    """(Exported, output treedef) from a program file, or None when it is missing or unreadable."""
    if path is None or not path.is_file():
        return None
    try:
        blob, out_tree = pickle.loads(path.read_bytes())
        return jax.export.deserialize(bytearray(blob)), out_tree
    except Exception:  # noqa: BLE001 - a truncated or foreign file: traced again and rewritten
        return None


def _write(path: Path | None, exp, out_tree) -> None:
    """Write a program file atomically (a concurrent reader sees the whole file or none); failures only cost a
    later process the trace."""
    if path is None:
        return
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_bytes(pickle.dumps((bytes(exp.serialize()), out_tree)))
        os.replace(tmp, path)
    except Exception:  # noqa: BLE001
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)


class _Program:
    """One argument signature's program: the exported one (``exp``, ``out_tree``), or plain jit (``exp`` None)."""

    def __init__(self, fn, name, donate, exp=None, out_tree=None, traced=False):
        self.exp, self.out_tree, self.traced = exp, out_tree, traced
        if exp is None:
            self.jit = jax.jit(fn, donate_argnums=donate)
        else:
            def call(*leaves):
                return exp.call(*leaves)

            call.__name__ = call.__qualname__ = name  # what JAX's compile log names it
            self.jit = jax.jit(call, donate_argnums=donate)


class Stored:
    """``jax.jit(fn, donate_argnums)`` whose programs are exported and kept in ``program_dir()`` (module doc).
    ``key``: everything ``fn`` closes over that changes its program (a config, arrays baked in as constants).
    Call it like the jitted function; ``lower(*args)`` lowers it for arguments' shapes (arrays or
    ``jax.ShapeDtypeStruct``) to compile ahead of time; ``eval_shape(*args)`` gives its outputs' shapes from a kept
    program without tracing. ``traces``: how many programs this object traced (not loaded)."""

    def __init__(self, fn, name: str, key, donate_argnums: tuple[int, ...] = ()):
        self.fn, self.name, self.donate = fn, name, tuple(donate_argnums)
        self.key = digest(key)
        self._programs: dict = {}
        self._lock = threading.Lock()

    @property
    def traces(self) -> int:
        return sum(p.traced for p in self._programs.values())

    def _flat(self, args):
        leaves, tree = jax.tree.flatten(args)
        return leaves, tree, tuple((tuple(x.shape), str(x.dtype)) for x in leaves)

    def _program(self, args) -> tuple[_Program, list]:
        leaves, tree, avals = self._flat(args)
        with self._lock:
            prog = self._programs.get((tree, avals))
            if prog is None:
                prog = self._programs[(tree, avals)] = self._build(args, leaves, tree, avals)
        return prog, leaves

    def _donated_leaves(self, args) -> tuple[int, ...]:
        idx, start = [], 0
        for i, a in enumerate(args):
            n = len(jax.tree.leaves(a))
            if i in self.donate:
                idx.extend(range(start, start + n))
            start += n
        return tuple(idx)

    def _build(self, args, leaves, tree, avals) -> _Program:
        donate = self._donated_leaves(args)
        folder = program_dir()
        sig = digest(FORMAT, self.name, self.key, code_digest(), _context(), tree, avals)
        path = folder / f"{self.name}-{sig[:40]}{SUFFIX}" if folder is not None else None
        found = _read(path)
        if found is not None:
            return _Program(self.fn, self.name, donate, *found)
        out_trees = []

        def flat(*xs):
            out = self.fn(*jax.tree.unflatten(tree, xs))
            out_leaves, out_tree = jax.tree.flatten(out)
            out_trees.append(out_tree)
            return out_leaves

        flat.__name__ = flat.__qualname__ = self.name  # what JAX's compile events and speed.json call its tracing

        specs = [jax.ShapeDtypeStruct(x.shape, x.dtype) for x in leaves]
        try:
            exp = jax.export.export(jax.jit(flat), disabled_checks=[
                jax.export.DisabledSafetyCheck.custom_call("ALL")])(*specs)  # loaded only by this jax: no guarantee needed
        except Exception:  # noqa: BLE001 - not exportable here: plain jit, traced in every process
            return _Program(self.fn, self.name, tuple(i for i in self.donate if i < len(args)), traced=True)
        _write(path, exp, out_trees[-1])
        return _Program(self.fn, self.name, donate, exp, out_trees[-1], traced=True)

    def __call__(self, *args):
        prog, leaves = self._program(args)
        if prog.exp is None:
            return prog.jit(*args)
        return jax.tree.unflatten(prog.out_tree, prog.jit(*leaves))

    def lower(self, *args):
        prog, leaves = self._program(args)
        return prog.jit.lower(*args) if prog.exp is None else prog.jit.lower(*leaves)

    def eval_shape(self, *args):
        prog, _ = self._program(args)
        if prog.exp is None:
            return jax.eval_shape(self.fn, *args)
        return jax.tree.unflatten(prog.out_tree, [jax.ShapeDtypeStruct(a.shape, a.dtype) for a in prog.exp.out_avals])

    def _cache_size(self) -> int:
        return sum(p.jit._cache_size() for p in self._programs.values())


def stored(fn, name: str, key, donate_argnums: tuple[int, ...] = ()) -> Stored:
    """``Stored(fn, name, key, donate_argnums)``: see ``Stored``."""
    return Stored(fn, name, key, donate_argnums)


__all__ = ["Stored", "stored", "code_digest", "digest", "program_dir", "FORMAT", "SUFFIX"]
