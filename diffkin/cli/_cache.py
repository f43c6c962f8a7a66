"""JAX's persistent compilation cache for the command line: where it is, and switching it on."""

from __future__ import annotations

import os
from pathlib import Path

from diffkin.cli._errors import CLIError

_CACHE_OFF = ("", "0", "off", "false", "no", "none")  # DIFFKIN_CACHE_DIR values that disable the cache
_CACHE_MIN_SECONDS = 0.1  # compilations at least this long are cached (JAX's default, 1 s, skips FK)


def cache_dir(option: str | None = None, disabled: bool = False) -> Path | None:
    """The folder of JAX's persistent compilation cache for this run, or ``None`` (no cache).

    In order: ``--no-cache`` (``disabled``) turns it off; ``--cache-dir`` (``option``) names it;
    else the environment variable ``DIFFKIN_CACHE_DIR`` names it (empty, ``0``, ``off``, ``false``,
    ``no`` or ``none`` turn it off); else ``$XDG_CACHE_HOME/diffkin/jax`` (default
    ``~/.cache/diffkin/jax``).
    """
    if disabled:
        return None
    if option is not None:
        return Path(option).expanduser()
    env = os.environ.get("DIFFKIN_CACHE_DIR")
    if env is not None:
        return None if env.strip().lower() in _CACHE_OFF else Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "diffkin" / "jax"


def use_cache(folder: Path | None, chosen: bool = True) -> None:
    """Point JAX's persistent compilation cache at ``folder`` (compilations of 0.1 s or more).

    A folder that cannot be created is an error if the user ``chosen`` it, else the cache stays off.
    """
    if folder is None:
        return
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        if not chosen:
            return
        raise CLIError(f"--cache-dir: cannot create {str(folder)!r}: {e.strerror}") from None
    import jax

    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", _CACHE_MIN_SECONDS)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
