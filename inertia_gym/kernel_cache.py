"""Key numba's on-disk cache of the compiled kernels by their sources.

numba reuses a cached kernel while the kernel's own file is unchanged; it does not notice a
change to a function it calls from another file. The simulation loop (simulation.py) compiles
the EKF step (estimation/ekf.py) and the integrator (dynamics.py) into itself, so after an edit
to either the cached loop would go on running the old code. Here the cache goes to a folder
named by a hash of every source file of the package that defines kernels: any edit to one of
them starts from an empty cache (one compile, most of it the simulation loop: about a
minute on a 2-core machine, in a thread of its own, simulation.compile_loop) and
nothing stale is ever run.

:func:`use_source_keyed_cache` must run before the first kernel module is imported;
``inertia_gym/__init__.py`` calls it. The folder is ``<package>/__pycache__/numba-<hash>`` (or
``$NUMBA_CACHE_DIR/inertia_gym-<hash>`` when that is set); where it cannot be written, numba
falls back to its default locations. In the package's own ``__pycache__`` only the
:data:`KEEP_VERSIONS` most recently used folders are kept (a day of editing kernels leaves
some 14 folders, 75 MB); a folder named by ``$NUMBA_CACHE_DIR`` is the user's and never pruned.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import numba

PACKAGE = Path(__file__).resolve().parent
KERNEL_MARK = "nb.njit"
KEEP_VERSIONS = 3


def kernel_sources(root: Path = PACKAGE) -> list[Path]:
    """The .py files under `root` that define numba kernels (contain ``nb.njit``), sorted."""
    return sorted(p for p in root.rglob("*.py")
                  if "__pycache__" not in p.parts and KERNEL_MARK in p.read_text(encoding="utf-8"))


def sources_digest(root: Path = PACKAGE) -> str:
    """16 hex digits of SHA-256 over the kernel sources' relative paths and contents."""
    h = hashlib.sha256()
    for path in kernel_sources(root):
        h.update(path.relative_to(root).as_posix().encode() + b"\0")
        h.update(path.read_bytes() + b"\0")
    return h.hexdigest()[:16]


def use_source_keyed_cache() -> Path:
    """Point numba's cache at the folder of this version of the kernels; return it."""
    user_dir = numba.config.CACHE_DIR
    if user_dir:
        folder = Path(user_dir) / f"inertia_gym-{sources_digest()}"
    else:
        folder = PACKAGE / "__pycache__" / f"numba-{sources_digest()}"
        prune_stale_caches(folder)
    numba.config.CACHE_DIR = str(folder)
    return folder


def prune_stale_caches(current: Path, keep: int = KEEP_VERSIONS) -> list[Path]:
    """Mark `current` as used now and delete all but the `keep` most recently used sibling
    ``numba-*`` folders (including `current`); return the deleted ones. Best effort: a folder
    that cannot be touched or removed (read-only install, another process) is left alone.
    """
    try:
        current.mkdir(parents=True, exist_ok=True)
        os.utime(current)
    except OSError:
        return []
    used_at = {}
    for folder in current.parent.glob("numba-*"):
        try:  # another process (a test worker importing too) may delete it meanwhile
            if folder != current and folder.is_dir():
                used_at[folder] = folder.stat().st_mtime
        except OSError:
            continue
    stale = sorted(used_at, key=used_at.get, reverse=True)[max(keep - 1, 0):]
    for folder in stale:
        shutil.rmtree(folder, ignore_errors=True)
    return stale


def use_fork_safe_threading() -> str:
    """Run the parallel kernels on numba's fork-safe "workqueue" threading layer, unless the user
    chose one with $NUMBA_THREADING_LAYER; returns the layer asked for.

    With GNU OpenMP (numba's default where it is installed), a process that has run a parallel
    kernel cannot fork: ``gym.make_vec(..., vectorization_mode="async")`` and SB3's
    ``SubprocVecEnv`` (fork start method) die with "fork() called from a process already using
    GNU OpenMP". The workqueue layer forks safely; it must not be entered from two Python
    threads at once (the package never does; run batches in processes, as executors.py does).
    """
    if not os.environ.get("NUMBA_THREADING_LAYER"):
        numba.config.THREADING_LAYER = "workqueue"
    return numba.config.THREADING_LAYER

