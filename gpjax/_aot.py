"""Compiled programs kept on disk, so a second process skips tracing, lowering and XLA.

JAX's persistent compilation cache (:mod:`gpjax._jaxcache`) saves only XLA's work: every
process still traces each function in Python and lowers it before it can look the
compiled program up — seconds per run for the batched simulator, the refiner and the
reference solve. A :class:`Program` keeps the *executable* itself
(``jax.experimental.serialize_executable``) under ``<cache folder>/programs``, keyed by:

* the function's name and a **fingerprint** of everything it closes over (the caller
  hashes its record and settings with :func:`fingerprint`);
* the shapes and dtypes of its arguments;
* the jax and jaxlib versions, the backend and its devices;
* a digest of gpjax's own source, so any change of the code compiles afresh.

A program that cannot be serialised or loaded is compiled as ``jax.jit`` would; a damaged
file is compiled again and overwritten. ``GPJAX_COMPILATION_CACHE=off`` keeps programs in
memory only. The folder holds at most :data:`MAX_PROGRAM_BYTES`: storing a program deletes
the least recently used ones beyond it (a load marks a file used), since every change of
gpjax's source or of the settings keys new files and the old ones would otherwise stay.

Within one process the last :data:`KEPT` executables are also kept in memory under the same
key, so a second record of the same shape and settings (``fit-many``'s next record on a
worker, the diagnosis' refits, a notebook's second fit) neither reads nor deserialises them.
"""

from __future__ import annotations

import collections
import hashlib
import os
import tempfile
import time
from functools import lru_cache, partial
from pathlib import Path
from typing import Callable

import jax
import jaxlib
import numpy as np
from jax.experimental.compilation_cache.compilation_cache import reset_cache

from ._jaxcache import cache_folder

#: Sub-folder of the cache folder holding the executables.
PROGRAMS = "programs"
#: Executables a process keeps in memory across programs of the same key.
KEPT = 32
#: Most bytes the programs folder holds (module docstring). A fit of one length bucket
#: and settings stores ~10–20 programs of at most ~4 MB: 2 GiB keeps dozens of them.
MAX_PROGRAM_BYTES = 2 * 2 ** 30

_KEPT: collections.OrderedDict = collections.OrderedDict()
#: Seconds and executables that every :class:`Program` of this process compiled or loaded.
_LEDGER = [0.0, 0]


def compile_ledger() -> tuple[float, int]:
    """(seconds, executables) compiled or loaded by every :class:`Program` of this process
    so far (the population evaluator, refiner, sensitivity and reference programs alike):
    a run's figures are the difference across it."""
    return _LEDGER[0], _LEDGER[1]


def compiled_since(mark: tuple[float, int]) -> dict:
    """``compile_s`` and ``compiles`` of this process since :func:`compile_ledger` gave
    ``mark``."""
    return {"compile_s": _LEDGER[0] - mark[0], "compiles": _LEDGER[1] - mark[1]}


@lru_cache(maxsize=1)
def source_digest() -> str:
    """SHA-256 of every gpjax source file (names and contents)."""
    digest = hashlib.sha256()
    package = Path(__file__).resolve().parent
    for path in sorted(package.rglob("*.py")):
        digest.update(str(path.relative_to(package)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def fingerprint(*parts) -> str:
    """SHA-256 of ``parts``: numpy arrays by dtype, shape and bytes, dicts by sorted
    items, sequences item by item, anything else by ``repr``."""
    digest = hashlib.sha256()

    def add(value):
        if isinstance(value, (np.ndarray, jax.Array)):
            array = np.ascontiguousarray(np.asarray(value))
            digest.update(f"array{array.dtype.str}{array.shape}".encode())
            digest.update(array.tobytes())
        elif isinstance(value, dict):
            digest.update(b"dict")
            for key in sorted(value, key=repr):
                add(key)
                add(value[key])
        elif isinstance(value, (list, tuple)):
            digest.update(f"seq{len(value)}".encode())
            for item in value:
                add(item)
        else:
            digest.update(repr(value).encode())
        digest.update(b"|")

    add(parts)
    return digest.hexdigest()


class Program:
    """``jax.jit(fn)`` whose executables persist between processes (module docstring).

    ``fn`` takes arrays (or pytrees of arrays) positionally; a call returns the leaves
    of its result as a flat tuple.

    Args:
        fn: the function to compile.
        name: a name unique among gpjax's programs.
        key: fingerprint of what ``fn`` closes over (:func:`fingerprint`).
    """

    def __init__(self, fn: Callable, *, name: str, key: str):
        self._fn = fn
        self._name = name
        self._key = key
        self._executables: dict[tuple, Callable] = {}
        #: Seconds spent tracing and compiling, or loading, executables (not running them).
        self.compile_seconds = 0.0

    @property
    def compile_count(self) -> int:
        """Executables compiled or loaded (one per argument signature)."""
        return len(self._executables)

    def __call__(self, *args):
        return self.prepared(*args)()

    def prepared(self, *args) -> Callable[[], tuple]:
        """The call with ``args``, its executable compiled or loaded now, run when the
        returned function is called: it may run in another thread (compiling switches
        JAX's process-wide cache setting, :func:`_compile_bypassing_persistent_cache`,
        so it stays in the calling one)."""
        leaves, tree = jax.tree_util.tree_flatten(args)
        signature = (str(tree), tuple((np.shape(x), np.dtype(getattr(x, "dtype", None)
                                                            or np.result_type(x)).str)
                                      for x in leaves))
        executable = self._executables.get(signature)
        if executable is None:
            began = time.perf_counter()
            executable = self._executables[signature] = self._executable(tree, leaves,
                                                                        signature)
            elapsed = time.perf_counter() - began
            self.compile_seconds += elapsed
            _LEDGER[0] += elapsed
            _LEDGER[1] += 1
        return partial(executable, *leaves)

    def _executable(self, tree, leaves, signature) -> Callable:
        def flat(*values):
            return tuple(jax.tree_util.tree_leaves(
                self._fn(*jax.tree_util.tree_unflatten(tree, values))))

        name = fingerprint(self._name, self._key, signature, jax.__version__,
                           jaxlib.__version__, [(d.platform, d.device_kind)
                                                for d in jax.devices()], source_digest(),
                           os.environ.get("XLA_FLAGS", ""))  # options compiled in
        kept = (str(cache_folder()), name)  # the folder too: each folder gets its file
        executable = _KEPT.pop(kept, None)
        if executable is None:
            executable = self._built(name, flat, leaves)
        _KEPT[kept] = executable
        while len(_KEPT) > KEPT:
            _KEPT.popitem(last=False)
        return executable

    def _built(self, name: str, flat: Callable, leaves) -> Callable:
        """The executable ``name`` loaded from the cache folder, else compiled (and
        stored there)."""
        folder = cache_folder()
        if folder is None:
            return jax.jit(flat).lower(*leaves).compile()
        path = folder / PROGRAMS / f"{self._name}-{name[:32]}.bin"
        loaded = _load(path, len(leaves))
        if loaded is not None:
            return loaded
        # Compiled by XLA itself: an executable loaded from JAX's own cache in this
        # process serialises without the code of its kernels.
        compiled = _compile_bypassing_persistent_cache(
            lambda: jax.jit(flat).lower(*leaves).compile())
        _store(path, compiled)
        return compiled


def _load(path: Path, n_inputs: int) -> Callable | None:
    """The executable stored at ``path``, or ``None`` if absent or unreadable."""
    from jax.experimental import serialize_executable

    try:
        payload = path.read_bytes()
    except OSError:
        return None
    try:
        _initialize_custom_calls()
        n_outputs, n_devices = (int.from_bytes(payload[k:k + 4], "little") for k in (0, 4))
        ids = [int.from_bytes(payload[8 + 4 * k:12 + 4 * k], "little")
               for k in range(n_devices)]
        devices = {d.id: d for d in jax.devices()}
        in_tree = jax.tree_util.tree_structure((tuple(range(n_inputs)), {}))
        out_tree = jax.tree_util.tree_structure(tuple(range(n_outputs)))
        loaded = serialize_executable.deserialize_and_load(
            payload[8 + 4 * n_devices:], in_tree, out_tree,
            execution_devices=[devices[i] for i in ids])
    except Exception:  # noqa: BLE001 - a damaged or foreign file is compiled afresh
        return None
    _touch(path)
    return loaded


def _compile_bypassing_persistent_cache(compile: Callable):
    """``compile()`` by XLA itself, JAX's persistent cache switched off for the call (and
    re-initialised afterwards with the user's settings)."""
    enabled = jax.config.jax_enable_compilation_cache
    jax.config.update("jax_enable_compilation_cache", False)
    reset_cache()
    try:
        return compile()
    finally:
        jax.config.update("jax_enable_compilation_cache", enabled)
        reset_cache()


def _initialize_custom_calls() -> None:
    """Bind LAPACK's routines for the CPU custom calls of linear solves. JAX does this
    when it lowers such a call (and when ``jax.export`` loads one); a loaded executable
    that was never lowered in this process would call unbound routines."""
    from jax._src.lax import linalg

    linalg.initialize_lapack()


def _store(path: Path, compiled) -> None:
    """Write ``compiled``'s executable to ``path`` atomically, after its output count and
    the ids of the devices it runs on (loaded, it runs on those: by default JAX would
    load it for every local device, and with several host devices a program of one device
    then asked for a shard per device); skipped where the backend cannot serialise it or
    the folder is not writable."""
    from jax.experimental import serialize_executable

    try:
        payload, _, out_tree = serialize_executable.serialize(compiled)
        ids = [d.id for d in compiled.runtime_executable().local_devices()]
        header = b"".join(n.to_bytes(4, "little") for n in [out_tree.num_leaves, len(ids), *ids])
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(handle, "wb") as file:
            file.write(header + payload)
        os.replace(temporary, path)
    except Exception:  # noqa: BLE001 - caching is an optimisation, never a failure
        return
    prune(path.parent, keep=path)


def _touch(path: Path) -> None:
    """Mark ``path`` used now (its modification time: the pruning's order)."""
    try:
        os.utime(path)
    except OSError:  # a read-only folder: the file is used all the same
        pass


def prune(folder: Path, *, keep: Path, max_bytes: int = MAX_PROGRAM_BYTES) -> None:
    """Delete the least recently used program files of ``folder`` (oldest modification
    time first) until the rest hold at most ``max_bytes``; ``keep`` (the file just
    stored) stays. Files another process deletes meanwhile are skipped."""
    files = []
    for path in folder.glob("*.bin"):
        try:
            status = path.stat()
        except OSError:
            continue
        files.append((status.st_mtime, status.st_size, path))
    total = sum(size for _, size, _ in files)
    for _, size, path in sorted(files, key=lambda item: item[0]):
        if total <= max_bytes:
            break
        if path == keep:
            continue
        try:
            path.unlink()
        except OSError:
            continue
        total -= size


class CompileFigures:
    """Mixin: the compile figures of an object whose programs are its :class:`Program`
    attributes (``_run`` and any other)."""

    _run: Program

    def _programs(self) -> list[Program]:
        return [p for p in vars(self).values() if isinstance(p, Program)]

    @property
    def compile_seconds(self) -> float:
        """Seconds spent compiling or loading the object's programs (not running them)."""
        return sum(p.compile_seconds for p in self._programs())

    @property
    def compile_count(self) -> int:
        """Programs compiled or loaded (one per argument signature)."""
        return sum(p.compile_count for p in self._programs())
