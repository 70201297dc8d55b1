"""Saving a project to a real full disk and a real read-only disk (tmpfs mounts, root only):
one `GlobeviewError` line and no file, partial or temporary, left behind; the project that
was there before stays whole (issue #26 item 4: nothing partial left)."""

from __future__ import annotations

from pathlib import Path

import pytest

from globeview.errors import GlobeviewError

from .contract import fill_disk, remount_readonly


def _globe_with_bookmarks(n: int):
    """A globe whose project is several kilobytes (``n`` bookmarks): it cannot fit in a
    nearly full disk's last bytes."""
    import globeview
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings

    globe = globeview.Globe(registry=PluginRegistry(MemorySettings()).discover())
    for i in range(n):
        globe.add_bookmark(f"view {i}", (-71.0 + i * 1e-3, 44.0, 5000.0))
    return globe


def test_a_full_disk_leaves_the_old_project_whole(mount_tmpfs) -> None:
    disk = mount_tmpfs("full", size="64k")
    old = disk / "p.toml"
    _globe_with_bookmarks(1).save_project(old)
    before = old.read_bytes()
    fill_disk(disk)
    with pytest.raises(GlobeviewError) as info:
        _globe_with_bookmarks(400).save_project(old)
    assert "\n" not in str(info.value) and "space" in str(info.value).lower()
    assert old.read_bytes() == before
    assert sorted(p.name for p in disk.iterdir()) == ["filler.bin", "p.toml"]


def test_a_read_only_disk_is_one_line_and_no_file(mount_tmpfs) -> None:
    disk: Path = mount_tmpfs("ro", size="64k")
    remount_readonly(disk)
    with pytest.raises(GlobeviewError) as info:
        _globe_with_bookmarks(1).save_project(disk / "p.toml")
    assert "\n" not in str(info.value)
    assert list(disk.iterdir()) == []
