"""JAX's persistent compilation cache for gpjax: a second run on the same shapes (same
record length, step count, population batch) loads its compiled programs from disk
instead of running XLA again.

Turned on by :func:`enable_compilation_cache` when gpjax first computes (beside the
switch to float64, :func:`gpjax._integrate.enable_float64`), never at import. The folder
is ``$GPJAX_CACHE_DIR`` or the platform's user cache folder (``~/.cache/gpjax/jax`` on
Linux); ``GPJAX_COMPILATION_CACHE=off`` leaves JAX's cache settings alone. A cache folder
the user set for JAX itself (``jax_compilation_cache_dir``) is kept. The cache takes
effect only if gpjax's first compile is the process's first (JAX decides once).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

#: Environment variable naming the cache folder.
CACHE_DIR_VARIABLE = "GPJAX_CACHE_DIR"
#: Environment variable that switches the cache off (``off``, ``0``, ``false``, ``no``).
SWITCH_VARIABLE = "GPJAX_COMPILATION_CACHE"
OFF = ("off", "0", "false", "no")


def cache_folder() -> Path | None:
    """The compilation cache folder gpjax uses, or ``None`` when it is switched off."""
    if os.environ.get(SWITCH_VARIABLE, "").strip().lower() in OFF:
        return None
    if os.environ.get(CACHE_DIR_VARIABLE):
        return Path(os.environ[CACHE_DIR_VARIABLE]).expanduser()
    if sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    elif sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA", Path.home() / "AppData" / "Local"))
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "gpjax" / "jax"


def enable_compilation_cache() -> None:
    """Point JAX's persistent compilation cache at :func:`cache_folder` (every compiled
    program is stored, however fast it compiled), unless switched off or already set."""
    import jax

    folder = cache_folder()
    if folder is None or jax.config.jax_compilation_cache_dir:
        return
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
