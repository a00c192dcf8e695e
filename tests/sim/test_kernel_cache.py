"""The compiled kernels are cached per version of all kernel sources (sim.kernel_cache)."""

from __future__ import annotations

import os
import re

from sim import kernel_cache as kc


def test_the_list_of_kernel_sources_is_every_module_that_imports_numba():
    found = set()
    for top in ("sim", "monitor", "drivers"):
        for path in (kc.ROOT / top).rglob("*.py"):
            if re.search(r"^\s*(import numba|from numba)", path.read_text(), re.M):
                found.add(path.relative_to(kc.ROOT).as_posix())
    assert found == set(kc.KERNEL_SOURCES)


def test_a_changed_source_changes_the_folder(tmp_path):
    for rel in kc.KERNEL_SOURCES:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("x = 1\n")
    before = kc.fingerprint(tmp_path)
    assert kc.fingerprint(tmp_path) == before
    callee = tmp_path / "sim/dexel_store.py"
    callee.write_text("x = 2\n")                       # same size, another time
    os.utime(callee, ns=(1, 1))
    assert kc.fingerprint(tmp_path) != before


def test_numba_caches_in_this_versions_folder(tmp_path, monkeypatch):
    import numba

    assert numba.config.CACHE_DIR or os.environ.get("NUMBA_CACHE_DIR")
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(numba.config, "CACHE_DIR", numba.config.CACHE_DIR)
    for k in range(kc.KEEP + 2):                       # older versions' folders
        (tmp_path / "dexmon" / "numba" / f"old{k}").mkdir(parents=True)
        os.utime(tmp_path / "dexmon" / "numba" / f"old{k}", (k, k))
    folder = kc.use_fingerprinted_cache()
    assert folder == tmp_path / "dexmon" / "numba" / kc.fingerprint()
    assert numba.config.CACHE_DIR == str(folder)
    assert len(list(folder.parent.iterdir())) == kc.KEEP  # the newest kept, this one among them


def test_a_cache_folder_the_user_chose_wins(monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", "/somewhere/chosen")
    assert kc.use_fingerprinted_cache() is None
