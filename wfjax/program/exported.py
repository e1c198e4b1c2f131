"""Sweep programs kept on disk as serialized StableHLO (``jax.export``), so a warm process
loads its program instead of tracing it.

Tracing and lowering the sweep's sharded batch of time loops took 1.2-1.4 s of a 3.9-4.9 s
warm ``wfjax sweep`` on the 2-core CPU, every process, although XLA's own compilation came
from JAX's persistent cache in 0.2 s. :func:`sharded_program` exports the program once
(``jax.export``, flattened to its array leaves, as wfjax's pytrees have no serialization
rules), stores the bytes in the wfjax cache (:mod:`wfjax._cache`), and later processes
deserialize them in milliseconds and compile ``Exported.call`` under the same compiler
options, which XLA's persistent cache then serves. The results are the same to the bit.

The entry's key holds everything the traced program depends on besides its array leaves:
the leaves' shapes and dtypes, the pytree structure with its static fields, the statics,
the device count and platform, the versions of jax, jaxlib and numpy, JAX's default matmul
precision, and a hash of the wfjax sources (an edited loop never loads an older program).
A structure whose printed form could hide a value (a truncated array, an object's address)
is not cached; nor is a program when serialization is unavailable (the ``flatbuffers``
package missing): those are traced as before.
"""

from __future__ import annotations

import functools
import hashlib
import re
from pathlib import Path

import jax
import numpy as np
from jax.sharding import Mesh, PartitionSpec

from .._cache import key_hash, load_or_build
from .._xla import LOOP_COMPILER_OPTIONS

__all__ = ["sharded_program", "sources_hash"]

_LOADED: dict[str, _Loaded] = {}  # this process's programs by key hash
_UNSAFE = re.compile(r"\.\.\.|0x[0-9a-f]{6,}|<[^<>]* object")


@functools.cache
def sources_hash() -> str:
    """SHA-256 hex digest of every ``.py`` file of the wfjax package (paths and contents)."""
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def _key(treedef, leaves, mesh: Mesh, statics, local=None) -> dict | None:
    """The cache key of the program ``local`` (a function or a ``functools.partial``) of
    these arguments, or None when their structure cannot be keyed safely."""
    structure = str(treedef)
    if _UNSAFE.search(structure):
        return None
    import jaxlib

    fn = getattr(local, "func", local)
    return {"function": f"{getattr(fn, '__module__', '')}.{getattr(fn, '__qualname__', '')}",
            "structure": structure, "statics": repr(statics),
            "leaves": [str(jax.typeof(x)) for x in leaves],
            "devices": int(mesh.devices.size), "axes": list(mesh.axis_names),
            "platform": jax.default_backend(), "versions": [jax.__version__,
                                                           jaxlib.__version__, np.__version__],
            "matmul_precision": str(jax.config.jax_default_matmul_precision),
            "sources": sources_hash()}


def _flat_program(local, treedef, n_data: int, n_leaves: int, mesh: Mesh):
    """``local`` over flattened leaves: ``shard_map`` with the first ``n_data`` leaves
    replicated and the rest (the run columns) split over the mesh's ``runs`` axis."""
    def flat(*leaves):
        data, *columns = jax.tree.unflatten(treedef, leaves)
        return local(data, *columns)

    specs = (PartitionSpec(),) * n_data + (PartitionSpec("runs"),) * (n_leaves - n_data)
    return jax.jit(jax.shard_map(flat, mesh=mesh, in_specs=specs,
                                 out_specs=PartitionSpec("runs"), check_vma=False))


class _Loaded:
    """A program called like ``fn(data, *columns)``: its deserialized export, jitted."""

    def __init__(self, exported, traced):
        self.call = jax.jit(exported.call, compiler_options=LOOP_COMPILER_OPTIONS)
        self.traced = traced  # True when this process traced it (the cache's first use)

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


def sharded_program(local, mesh: Mesh, statics, data, columns, fallback, cache_dir=None):
    """The program ``local(data, *columns)`` sharded over ``mesh`` (the columns split over
    its ``runs`` axis), loaded from the wfjax cache when a process has exported it before.

    Args:
        local: the per-device function (pure), ``(data, *columns) -> dict`` of [n] outputs.
        mesh: the devices' mesh (axis ``runs``).
        statics: every Python value ``local`` closes over that shapes the program (hashable,
            with a faithful ``repr``).
        data, columns: example arguments (device arrays): their leaves' shapes and dtypes
            are the program's.
        fallback: the traced program ``fallback(data, *columns)`` used when this program
            cannot be cached (see the module's docstring).
        cache_dir: the wfjax cache directory (:func:`wfjax._cache.cache_directory`).

    Returns:
        a callable ``fn(data, *columns)`` with ``fn.lower(...).compile()`` as a jit's.
    """
    leaves, treedef = jax.tree.flatten((data, *columns))
    key = _key(treedef, leaves, mesh, statics, local)
    if key is None:
        return fallback
    memo = key_hash("sweep-program", key)
    if memo in _LOADED:
        return _LOADED[memo]
    n_data = len(jax.tree.leaves(data))
    traced = []

    def build():
        traced.append(True)
        program = _flat_program(local, treedef, n_data, len(leaves), mesh)
        avals = [jax.ShapeDtypeStruct(a.shape, a.dtype, weak_type=a.weak_type)
                 for a in map(jax.typeof, leaves)]
        return {"stablehlo": np.frombuffer(jax.export.export(program)(*avals).serialize(),
                                           np.uint8)}

    try:
        blob = load_or_build("sweep-program", key, build, cache_dir)["stablehlo"]
    except ImportError:  # jax.export's serialization needs the flatbuffers package
        return fallback
    loaded = _Loaded(jax.export.deserialize(bytearray(blob.tobytes())), bool(traced))
    _LOADED[memo] = loaded
    return loaded
