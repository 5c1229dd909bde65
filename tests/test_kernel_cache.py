import shutil
from pathlib import Path

import numba

import inertia_gym  # noqa: F401  (sets the cache folder)
from inertia_gym import kernel_cache, simulation
from inertia_gym.estimation import ekf


def _copy_tree(tmp_path: Path) -> Path:
    root = tmp_path / "pkg"
    for rel in ("estimation/ekf.py", "simulation.py", "scenario.py"):
        dst = root / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(kernel_cache.PACKAGE / rel, dst)
    return root


def test_digest_follows_every_kernel_source_and_nothing_else(tmp_path):
    root = _copy_tree(tmp_path)
    assert [p.relative_to(root).as_posix() for p in kernel_cache.kernel_sources(root)] == [
        "estimation/ekf.py", "simulation.py"]
    before = kernel_cache.sources_digest(root)
    # An edit to a callee in another file (the case numba's own cache misses) changes the key.
    ekf_py = root / "estimation" / "ekf.py"
    ekf_py.write_text(ekf_py.read_text().replace("cfg[C_NIS_GATE] * m", "cfg[C_NIS_GATE] * m * 2"))
    edited = kernel_cache.sources_digest(root)
    assert edited != before
    # A file without kernels does not.
    (root / "scenario.py").write_text("# edited\n" + (root / "scenario.py").read_text())
    assert kernel_cache.sources_digest(root) == edited


def test_compiled_kernels_are_cached_under_the_source_keyed_folder():
    folder = Path(numba.config.CACHE_DIR)
    assert folder.name.endswith(kernel_cache.sources_digest())
    for kernel in (simulation._segment_batch, ekf.ekf_update):
        assert Path(kernel._cache._cache_path).is_relative_to(folder)
