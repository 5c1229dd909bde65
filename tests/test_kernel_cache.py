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
    ekf_py.write_text(ekf_py.read_text().replace("cfg.nis_gate * m", "cfg.nis_gate * m * 2"))
    edited = kernel_cache.sources_digest(root)
    assert edited != before
    # A file without kernels does not.
    (root / "scenario.py").write_text("# edited\n" + (root / "scenario.py").read_text())
    assert kernel_cache.sources_digest(root) == edited


def test_compiled_kernels_are_cached_under_the_source_keyed_folder():
    folder = Path(numba.config.CACHE_DIR)
    assert folder.name.endswith(kernel_cache.sources_digest())
    for kernel in (simulation._segment_tasks, ekf.ekf_update):
        assert Path(kernel._cache._cache_path).is_relative_to(folder)


def test_only_the_most_recently_used_cache_folders_are_kept(tmp_path):
    import os

    old = []
    for age, name in enumerate(["numba-aaaa", "numba-bbbb", "numba-cccc", "numba-dddd"]):
        folder = tmp_path / name
        (folder / "sub").mkdir(parents=True)
        (folder / "sub" / "k.nbc").write_bytes(b"x")
        os.utime(folder, (1000.0 - age * 100, 1000.0 - age * 100))  # aaaa newest
        old.append(folder)
    other = tmp_path / "not-a-cache"
    other.mkdir()
    current = tmp_path / "numba-new0"
    removed = kernel_cache.prune_stale_caches(current, keep=3)
    assert sorted(p.name for p in removed) == ["numba-cccc", "numba-dddd"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "not-a-cache", "numba-aaaa", "numba-bbbb", "numba-new0"]
    # Coming back to an older version marks it used: it now outlives the others.
    kernel_cache.prune_stale_caches(tmp_path / "numba-bbbb", keep=2)
    assert sorted(p.name for p in tmp_path.glob("numba-*")) == ["numba-bbbb", "numba-new0"]


def test_a_folder_vanishing_during_the_prune_is_skipped(tmp_path, monkeypatch):
    """Two processes importing at once (pytest workers) prune the same folder: one of them sees
    a sibling disappear between listing and stat, and must carry on."""
    for name in ("numba-aaaa", "numba-gone", "numba-cccc"):
        (tmp_path / name).mkdir()
    real_stat = Path.stat

    def stat(self, *args, **kwargs):
        if self.name == "numba-gone":
            raise FileNotFoundError(self)
        return real_stat(self, *args, **kwargs)

    monkeypatch.setattr(Path, "stat", stat)
    removed = kernel_cache.prune_stale_caches(tmp_path / "numba-new0", keep=2)
    assert len(removed) == 1 and removed[0].name in ("numba-aaaa", "numba-cccc")
