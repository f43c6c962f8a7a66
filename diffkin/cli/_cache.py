"""The command line's cache options: ``--cache-dir DIR`` and ``--no-cache`` over the library's default cache."""

from __future__ import annotations

from diffkin._cache import cache_dir, use_cache
from diffkin.cli._errors import CLIError

__all__ = ["cache_dir", "use_options"]


def use_options(option: str | None, disabled: bool) -> None:
    """Apply ``--cache-dir`` (``option``) or ``--no-cache`` (``disabled``); without either, the cache
    ``import diffkin`` chose stays (:mod:`diffkin._cache`)."""
    if option is None and not disabled:
        return
    folder = cache_dir(option, disabled)
    try:
        use_cache(folder)
    except OSError as e:
        raise CLIError(f"--cache-dir: cannot create {str(folder)!r}: {e.strerror}") from None
