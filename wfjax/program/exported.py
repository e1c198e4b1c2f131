"""Programs kept on disk as serialized StableHLO (``jax.export``), so a warm process loads
them instead of tracing them.

Tracing and lowering the sweep's sharded batch of time loops took 1.2-1.4 s of a 3.9-4.9 s
warm ``wfjax sweep`` on the 2-core CPU, every process, although XLA's own compilation came
from JAX's persistent cache in 0.2 s; preparing a batch of parametric 3D laws (the Fig. 8
set's) took another 0.7 s. :func:`sharded_program` (the sweep's) and :func:`kept_jit` (any
one-device program: the laws' batch) export a program once (``jax.export``, flattened to its
array leaves, as wfjax's pytrees have no serialization rules; :func:`kept_jit` keeps its
output's structure as a pickled ``PyTreeDef``, read back by an unpickler that admits JAX's
tree classes and wfjax's types only), store the bytes in the wfjax cache
(:mod:`wfjax._cache`), and later processes deserialize them in milliseconds and compile
``Exported.call`` under the same compiler options, which XLA's persistent cache then
serves. The results are the same to the bit.

The entry's key holds everything the traced program depends on besides its array leaves:
the function's name, the leaves' shapes and dtypes, the pytree structure with its static
fields, the statics, the device count and platform, the versions of jax, jaxlib and numpy,
JAX's default matmul precision, and a hash of the wfjax sources (an edited loop never loads
an older program). A structure or statics whose printed form could hide a value (a truncated
array, an object's address) is not kept; nor is a program when serialization is unavailable
(the ``flatbuffers`` package missing): those are traced as before.
"""

from __future__ import annotations

import collections
import functools
import hashlib
import importlib.util
import io
import pickle
import re
from pathlib import Path

import jax
import numpy as np
from jax.sharding import Mesh, PartitionSpec

from .._cache import key_hash, load_or_build
from .._xla import loop_compiler_options

__all__ = ["sharded_program", "kept_jit", "sources_hash"]

# This process's programs by key hash, the most recently used last. Each holds its machine code
# in memory maps (about 300 for one run's history, 1,000 for a sweep's batch), so a process
# that simulated speed after speed (every speed a program: its step count shapes the history)
# would run into the kernel's vm.max_map_count (65,530) after ~200; the least recently used
# are dropped beyond MAX_LOADED_PROGRAMS (a dropped one reloads from the wfjax cache and
# XLA's persistent cache when the command line enabled it, else compiles again).
MAX_LOADED_PROGRAMS = 32
_LOADED: collections.OrderedDict = collections.OrderedDict()


def _recall(memo):
    """The loaded program of ``memo`` (marked as just used), or None."""
    program = _LOADED.get(memo)
    if program is not None:
        _LOADED.move_to_end(memo)
    return program


def _keep(memo, program):
    """Keep ``program`` under ``memo``, dropping the least recently used beyond
    MAX_LOADED_PROGRAMS; returns ``program``."""
    _LOADED[memo] = program
    _LOADED.move_to_end(memo)
    while len(_LOADED) > MAX_LOADED_PROGRAMS:
        _LOADED.popitem(last=False)
    return program
_UNSAFE = re.compile(r"\.\.\.|0x[0-9a-f]{6,}|<[^<>]* object")


@functools.cache
def sources_hash() -> str:
    """SHA-256 hex digest of every ``.py`` file of the wfjax package (paths and contents)."""
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def _key(treedef, leaves, devices: int, statics, local=None) -> dict | None:
    """The cache key of the program ``local`` (a function or a ``functools.partial``) of
    these arguments on ``devices`` devices, or None when their structure cannot be keyed
    safely."""
    structure = str(treedef)
    if _UNSAFE.search(structure + repr(statics)):
        return None
    import jaxlib

    fn = getattr(local, "func", local)
    return {"function": f"{getattr(fn, '__module__', '')}.{getattr(fn, '__qualname__', '')}",
            "structure": structure, "statics": repr(statics),
            "leaves": [str(jax.typeof(x)) for x in leaves], "devices": devices,
            "platform": jax.default_backend(), "versions": [jax.__version__,
                                                           jaxlib.__version__, np.__version__],
            "matmul_precision": str(jax.config.jax_default_matmul_precision),
            "sources": sources_hash()}


@functools.cache
def _serializable() -> bool:
    """Whether ``jax.export`` can serialize here (it needs the flatbuffers package)."""
    return importlib.util.find_spec("flatbuffers") is not None


def _entry(name: str, key: dict, build, cache_dir) -> dict | None:
    """The cache entry ``name``/``key`` (``build()`` on a miss), or None when programs cannot
    be serialized: checked before tracing, so a process without flatbuffers traces once."""
    if not _serializable():
        return None
    try:
        return load_or_build(name, key, build, cache_dir)
    except ImportError:  # jax.export's serialization needs the flatbuffers package
        return None


def _avals(leaves) -> list:
    return [jax.ShapeDtypeStruct(a.shape, a.dtype, weak_type=a.weak_type)
            for a in map(jax.typeof, leaves)]


def _as_bytes(data: bytes) -> np.ndarray:
    return np.frombuffer(data, np.uint8)


class _TreeUnpickler(pickle.Unpickler):
    """Reads back a pickled ``PyTreeDef`` and nothing else: JAX's tree classes and wfjax's
    own types only, so a cache entry cannot run other code."""

    def find_class(self, module, name):
        if (module, name) in (("jaxlib._jax.pytree", "PyTreeDef"),
                              ("jax._src.tree_util", "default_registry")) or (
                module.startswith("wfjax.") and isinstance(
                    getattr(__import__(module, fromlist=[name]), name, None), type)):
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"{module}.{name} is not a pytree node type")


def _out_tree(blob: np.ndarray):
    """The output ``PyTreeDef`` stored with a kept program, or None if unreadable."""
    try:
        return _TreeUnpickler(io.BytesIO(blob.tobytes())).load()
    except Exception:  # noqa: BLE001 - any unreadable structure means "trace instead"
        return None


def _flat_program(local, treedef, n_data: int, n_leaves: int, mesh: Mesh,
                  compiler_options=None):
    """``local`` over flattened leaves: ``shard_map`` with the first ``n_data`` leaves
    replicated and the rest (the run columns) split over the mesh's ``runs`` axis.

    ``shard_map`` gives every device its own batch of runs: the batched Newton
    ``while_loop`` then stops on the device's own runs, with no cross-device reduction of its
    condition at every step."""
    def flat(*leaves):
        data, *columns = jax.tree.unflatten(treedef, leaves)
        return local(data, *columns)

    specs = (PartitionSpec(),) * n_data + (PartitionSpec("runs"),) * (n_leaves - n_data)
    return jax.jit(jax.shard_map(flat, mesh=mesh, in_specs=specs,
                                 out_specs=PartitionSpec("runs"), check_vma=False),
                   compiler_options=compiler_options)


class _Loaded:
    """A program called like ``fn(data, *columns)``: ``call`` (a jit of the flattened
    leaves: a deserialized export's, or the traced program where it cannot be kept)."""

    def __init__(self, call, traced: bool):
        self.call = call
        self.traced = traced  # True when this process traced it

    def __call__(self, data, *columns):
        return self.call(*jax.tree.leaves((data, *columns)))

    def lower(self, data, *columns):
        """As ``jax.jit(...).lower``: ``.compile()`` gives a callable of the same arguments."""
        lowered = self.call.lower(*jax.tree.leaves((data, *columns)))
        return _Lowered(lowered)


class _Lowered:
    def __init__(self, lowered):
        self.lowered = lowered

    def compile(self):
        compiled = self.lowered.compile()
        return lambda data, *columns: compiled(*jax.tree.leaves((data, *columns)))


def sharded_program(local, mesh: Mesh, statics, data, columns, cache_dir=None):
    """The program ``local(data, *columns)`` sharded over ``mesh`` (the columns split over
    its ``runs`` axis), loaded from the wfjax cache when a process has exported it before,
    else traced (and kept, where it can be: see the module's docstring).

    Args:
        local: the per-device function (pure), ``(data, *columns) -> dict`` of [n] outputs.
        mesh: the devices' mesh (axis ``runs``).
        statics: every Python value ``local`` closes over that shapes the program (hashable,
            with a faithful ``repr``).
        data, columns: example arguments (device arrays): their leaves' shapes and dtypes
            are the program's.
        cache_dir: the wfjax cache directory (:func:`wfjax._cache.cache_directory`).

    Returns:
        a callable ``fn(data, *columns)`` with ``fn.lower(...).compile()`` as a jit's.
    """
    leaves, treedef = jax.tree.flatten((data, *columns))
    n_data = len(jax.tree.leaves(data))
    key = _key(treedef, leaves, int(mesh.devices.size), statics, local)
    memo = (key_hash("sweep-program", key) if key is not None
            else (local, treedef, n_data, len(leaves), mesh))
    if (known := _recall(memo)) is not None:
        return known
    traced = []

    def build():
        traced.append(True)
        program = _flat_program(local, treedef, n_data, len(leaves), mesh)
        return {"stablehlo": _as_bytes(jax.export.export(program)(*_avals(leaves))
                                       .serialize())}

    entry = None if key is None else _entry("sweep-program", key, build, cache_dir)
    if entry is None:  # not kept: traced in this process
        call = _flat_program(local, treedef, n_data, len(leaves), mesh, loop_compiler_options())
        loaded = _Loaded(call, True)
    else:
        exported = jax.export.deserialize(bytearray(entry["stablehlo"].tobytes()))
        loaded = _Loaded(jax.jit(exported.call, compiler_options=loop_compiler_options()),
                         bool(traced))
    return _keep(memo, loaded)


def kept_jit(fn, args: tuple, statics, cache_dir=None, compiler_options=None,
             fallback=None):
    """``jax.jit(fn)`` for arguments shaped as ``args`` (one device), loaded from the wfjax
    cache when a process has exported it before; any pytrees in and out.

    Args:
        fn: a pure function of ``*args``.
        args: example arguments (their leaves' shapes and dtypes are the program's).
        statics: every Python value ``fn`` closes over that shapes the program (with a
            faithful ``repr``).
        cache_dir: the wfjax cache directory.
        compiler_options: XLA options of the compiled program (``jax.jit``'s).
        fallback: the traced program where this one cannot be kept (see the module's
            docstring); default ``jax.jit(fn, compiler_options=compiler_options)``.

    Returns:
        a callable of arguments shaped as ``args``.
    """
    leaves, treedef = jax.tree.flatten(args)
    key = _key(treedef, leaves, 1, statics, fn)
    fallback = fallback or jax.jit(fn, compiler_options=compiler_options)
    if key is None:
        return fallback
    memo = key_hash("program", key)
    if (known := _recall(memo)) is not None:
        return known
    trees = []

    def flat(*leaves):
        out, tree = jax.tree.flatten(fn(*jax.tree.unflatten(treedef, leaves)))
        trees.append(tree)
        return out

    def build():
        exported = jax.export.export(jax.jit(flat))(*_avals(leaves))
        return {"stablehlo": _as_bytes(exported.serialize()),
                "out_tree": _as_bytes(pickle.dumps(trees[0]))}

    entry = _entry("program", key, build, cache_dir)
    out_tree = None if entry is None else _out_tree(entry["out_tree"])
    if out_tree is None:  # kept for the process, so its jit cache serves later calls
        return _keep(memo, fallback)
    call = jax.jit(jax.export.deserialize(bytearray(entry["stablehlo"].tobytes())).call,
                   compiler_options=compiler_options)
    return _keep(memo, lambda *a: jax.tree.unflatten(out_tree, call(*jax.tree.leaves(a))))
