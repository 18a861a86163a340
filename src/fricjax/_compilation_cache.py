"""JAX's persistent compilation cache for fricjax: compiled programs kept on disk, so that a second run of the
command line (or a new notebook kernel) loads them instead of compiling again.

`fricjax compare` and `fricjax demo` turn it on by default, in `default_cache_dir()` (`$FRICJAX_CACHE_DIR`, else
`$XDG_CACHE_HOME/fricjax/jax`, else `~/.cache/fricjax/jax`); `--no-cache` or `FRICJAX_NO_CACHE=1` turn it off. In a
notebook, one line: `fj.enable_compilation_cache()`. Every program is stored, however fast it compiles
(`MIN_COMPILE_SECONDS`): a default `fricjax compare` compiles about 300, 270 of them in under 0.2 s each, 8 s in
all; read back from the cache they cost a fraction of that (second run 16 s against 24 s with a 0.2 s threshold, the
first 37-44 s; 3.5 MB on disk; benchmarks/README.md). The cache is JAX's own
(`jax_compilation_cache_dir`), keyed by the program, the JAX version, the backend and the XLA flags; delete the
folder to clear it.
"""

from __future__ import annotations

import os
import pathlib

MIN_COMPILE_SECONDS = 0.0  # JAX's default is 1 s: most of fricjax's programs compile faster


def default_cache_dir() -> pathlib.Path:
    """Where fricjax keeps compiled programs: `$FRICJAX_CACHE_DIR`, else `$XDG_CACHE_HOME/fricjax/jax`, else
    `~/.cache/fricjax/jax`."""
    if os.environ.get("FRICJAX_CACHE_DIR"):
        return pathlib.Path(os.environ["FRICJAX_CACHE_DIR"]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or pathlib.Path.home() / ".cache"
    return pathlib.Path(base).expanduser() / "fricjax" / "jax"


def cache_disabled() -> bool:
    """Whether the user turned the command line's cache off (`FRICJAX_NO_CACHE` set to a non-empty value)."""
    return bool(os.environ.get("FRICJAX_NO_CACHE"))


def enable_compilation_cache(path: str | os.PathLike[str] | None = None) -> pathlib.Path | None:
    """Keep JAX's compiled programs in `path` (default: `default_cache_dir()`), for this process and the next ones.

    **Returns:** the folder, or None when it cannot be created (the cache then stays off; nothing else changes).

    ```python
    >>> import fricjax as fj
    >>> folder = fj.enable_compilation_cache()  # doctest: +SKIP
    ```
    """
    import jax

    folder = default_cache_dir() if path is None else pathlib.Path(path).expanduser()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return folder
