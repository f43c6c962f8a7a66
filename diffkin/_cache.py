"""JAX's persistent compilation cache, on by default: a script's second run reads back what its first compiled.

When ``diffkin.models`` is first imported (by any use of a model), JAX's cache is pointed at
``$DIFFKIN_CACHE_DIR``, else at ``$XDG_CACHE_HOME/diffkin/jax`` (``~/.cache/diffkin/jax``), with every
program kept (JAX's own default skips those compiling in under a second, most of a script's programs),
unless the user chose otherwise: ``DIFFKIN_CACHE_DIR=off`` (or empty, ``0``, ``false``, ``no``,
``none``) turns it off, and a cache the user configured for JAX (``JAX_COMPILATION_CACHE_DIR``,
``jax.config.jax_compilation_cache_dir``) is left as it is. ``import diffkin`` alone imports neither JAX
nor this. Nothing goes through the environment, so subprocesses choose for themselves. A process that
used the cache trims the folder to :data:`MAX_BYTES` at exit, oldest files first (JAX's own size bound
lists the folder on every write, which costs more than it saves when every small program is kept).
"""

from __future__ import annotations

import atexit
import os
from pathlib import Path

OFF = ("", "0", "off", "false", "no", "none")  # DIFFKIN_CACHE_DIR values that turn the cache off
MAX_BYTES = 2 * 2**30  # the folder's bound, kept at exit
_chosen = False  # whether use_cache ran: a choice made (by the CLI's options, say) stands
_KEEP_EVERY_PROGRAM = {  # JAX option -> value: every program is cached, however fast it compiled or small
    "jax_persistent_cache_min_compile_time_secs": 0,
    "jax_persistent_cache_min_entry_size_bytes": 0,
}


def cache_dir(option: str | None = None, disabled: bool = False) -> Path | None:
    """The folder of JAX's persistent compilation cache, or ``None`` (no cache).

    In order: ``disabled`` turns it off; ``option`` names it; else the environment variable
    ``DIFFKIN_CACHE_DIR`` names it (empty, ``0``, ``off``, ``false``, ``no`` or ``none`` turn it off);
    else ``$XDG_CACHE_HOME/diffkin/jax`` (default ``~/.cache/diffkin/jax``).
    """
    if disabled:
        return None
    if option is not None:
        return Path(option).expanduser()
    env = os.environ.get("DIFFKIN_CACHE_DIR")
    if env is not None:
        return None if env.strip().lower() in OFF else Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "diffkin" / "jax"


def use_cache(folder: Path | None) -> None:
    """Point JAX's persistent compilation cache at ``folder``, keeping every program; ``None`` turns it off.
    The choice stands: :func:`use_cache_by_default` does not change it afterwards.

    Raises:
        OSError: ``folder`` cannot be created.
    """
    global _chosen
    _chosen = True
    if folder is not None:
        folder.mkdir(parents=True, exist_ok=True)
    import jax
    from jax.experimental.compilation_cache import compilation_cache

    jax.config.update("jax_compilation_cache_dir", None if folder is None else str(folder))
    for option, value in _KEEP_EVERY_PROGRAM.items():
        jax.config.update(option, value)
    compilation_cache.reset_cache()  # JAX decides once per process whether it caches: decide again
    if folder is not None:
        _trim_at_exit(folder)


def use_cache_by_default() -> None:
    """Switch the cache on as the module docstring says (called when ``diffkin.models`` is imported)."""
    import jax

    folder = cache_dir()
    configured = jax.config.jax_compilation_cache_dir is not None  # type: ignore[attr-defined]  # untyped flag
    if _chosen or folder is None or configured:
        return
    try:
        use_cache(folder)
    except OSError:  # a read-only home, say: no cache, nothing else changes
        return


_TRIMMED: set[Path] = set()


def _trim_at_exit(folder: Path) -> None:
    if folder not in _TRIMMED:
        _TRIMMED.add(folder)
        atexit.register(trim, folder, MAX_BYTES)


def trim(folder: Path, max_bytes: int) -> None:
    """Delete the oldest files of ``folder`` (by modification time, subfolders included) until it holds at
    most ``max_bytes``; files another process removes meanwhile are skipped."""
    files = []
    for path in folder.rglob("*"):
        try:
            if path.is_file():
                stat = path.stat()
                files.append((stat.st_mtime, stat.st_size, path))
        except OSError:
            continue
    total = sum(size for _, size, _ in files)
    for _, size, path in sorted(files):
        if total <= max_bytes:
            break
        path.unlink(missing_ok=True)
        total -= size
