"""Store backends as a seam: the built-ins are found through the entry-point group
``globeview.store_backends``, and a third party's backend, built into a wheel and installed
with pip, is found the same way and used by every opener (`open_source`, `TileStore.open`, the
command line); a backend that raises is reported in one line and skipped."""

from __future__ import annotations

import base64
import hashlib
import importlib
import logging
import os
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import numpy as np
import pytest

from globeview.errors import StoreError
from globeview.terrain.ingest.driver import ingest
from globeview.terrain.sources import check_source, open_source, source_kind
from globeview.terrain.store.backend import ENTRY_POINT_GROUP, find_backend, store_backends
from globeview.terrain.store.http import HttpBackend
from globeview.terrain.store.local import LocalBackend
from globeview.terrain.store.tile_store import TileStore

DATA = Path(__file__).resolve().parents[2] / "data"
SMALL = DATA / "craterlake-elev-16bit-30m.tif"
GLOBEVIEW = Path(sys.executable).parent / "globeview"

#: A third party's package: a ``demo://FOLDER`` backend (a store folder read through its own
#: `StoreFiles`, counting what it opens), one that raises in ``can_open`` and one whose
#: ``open`` has a bug.
DEMO_MODULE = """
    import hashlib
    from pathlib import Path

    import rasterio

    from globeview.errors import StoreError
    from globeview.terrain.store.backend import StoreFiles

    OPENED = []


    class DemoFiles(StoreFiles):
        def __init__(self, folder):
            self.folder = self.path = Path(folder)
            self.location = f"demo://{folder}"

        def read_manifest(self, name):
            try:
                return (self.folder / name).read_bytes()
            except OSError:
                raise StoreError(f"{self.location} is not a globeview tile store") from None

        def describe(self, name):
            return f"{self.location}/{name}"

        def open_raster(self, name, sha256):
            OPENED.append(name)
            return rasterio.open(self.folder / name)

        def sha256(self, name):
            return hashlib.sha256((self.folder / name).read_bytes()).hexdigest()


    class DemoBackend:
        priority = 10

        def can_open(self, text):
            return text.startswith("demo://")

        def check(self, text):
            if not text[len("demo://"):]:
                raise StoreError("demo:// needs a folder")
            return text.strip()

        def open(self, text, options=None):
            return DemoFiles(text[len("demo://"):])


    class RaisingBackend:
        def can_open(self, text):
            raise RuntimeError("boom in can_open")

        def open(self, text, options=None):
            raise AssertionError("never asked")


    class BuggyBackend:
        def can_open(self, text):
            return text.startswith("buggy://")

        def open(self, text, options=None):
            return 1 / 0
"""

ENTRY_POINTS = f"""[{ENTRY_POINT_GROUP}]
demo = gv_demo_store:DemoBackend
raising = gv_demo_store:RaisingBackend
buggy = gv_demo_store:BuggyBackend
"""


#: What the backend raising in ``can_open`` costs: one warning line, never an error.
RAISING_LINE = (
    "store backend raising failed in can_open and was skipped: RuntimeError: boom in can_open"
)


PIP_INSTALL = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-index"]


def _record_hash(data: bytes) -> str:
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"sha256={digest},{len(data)}"


def _wheel(folder: Path) -> Path:
    """The third party's wheel, as a build backend writes it (no build tools needed)."""
    info = "gv_demo_store-0.1.0.dist-info"
    files = {
        "gv_demo_store/__init__.py": textwrap.dedent(DEMO_MODULE).encode(),
        f"{info}/METADATA": b"Metadata-Version: 2.1\nName: gv-demo-store\nVersion: 0.1.0\n",
        f"{info}/WHEEL": (
            b"Wheel-Version: 1.0\nGenerator: globeview-tests\nRoot-Is-Purelib: true\n"
            b"Tag: py3-none-any\n"
        ),
        f"{info}/entry_points.txt": ENTRY_POINTS.encode(),
    }
    record = "".join(f"{name},{_record_hash(data)}\n" for name, data in files.items())
    files[f"{info}/RECORD"] = (record + f"{info}/RECORD,,\n").encode()
    path = folder / "gv_demo_store-0.1.0-py3-none-any.whl"
    with zipfile.ZipFile(path, "w") as z:
        for name, data in files.items():
            z.writestr(name, data)
    return path


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder the third party's wheel is pip-installed into (``pip install --target``)."""
    root = tmp_path_factory.mktemp("backend-site")
    wheel = _wheel(tmp_path_factory.mktemp("wheel"))
    target = root / "site"
    res = subprocess.run(
        [*PIP_INSTALL, "--target", str(target), str(wheel)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    assert (target / "gv_demo_store-0.1.0.dist-info" / "entry_points.txt").is_file()
    return target


@pytest.fixture
def installed(site: Path, monkeypatch: pytest.MonkeyPatch):
    """The third party's backends on ``sys.path`` for one test (gone afterwards)."""
    monkeypatch.syspath_prepend(str(site))
    importlib.invalidate_caches()
    yield importlib.import_module("gv_demo_store")
    sys.modules.pop("gv_demo_store", None)
    importlib.invalidate_caches()


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("stores") / "crater"
    ingest([SMALL], out)
    return out


def test_the_built_ins_are_entry_points() -> None:
    names = dict(store_backends())
    assert isinstance(names["local"], LocalBackend) and isinstance(names["http"], HttpBackend)
    assert find_backend("https://host/store")[0] == "http"
    assert find_backend("./nowhere") is None  # no folder with a manifest there: a DEM path


@pytest.mark.slow
def test_a_pip_installed_backend_is_found_and_used(installed, store: Path, caplog) -> None:
    caplog.set_level(logging.WARNING, logger="globeview.terrain.store")
    order = [name for name, _ in store_backends()]
    assert order.index("demo") < order.index("local")  # priority 10 is asked first
    text = f"demo://{store}"
    assert source_kind(text) == "store" and check_source(text) == text
    with open_source(text) as st:
        assert st.location == text and st.path == store and not st.is_remote
        level, grid = st.max_level, st.level_grid(st.max_level)
        ys, xs = np.mgrid[grid.y0 : grid.y0 + grid.ny, grid.x0 : grid.x0 + grid.nx]
        has = st.has_data(level, xs % grid.ncols, ys)  # from the shards, read by the backend
        iy, ix = np.argwhere(has)[0]
        heights = st.heights((level, (grid.x0 + int(ix)) % grid.ncols, grid.y0 + int(iy)))
        assert np.isfinite(heights).any()
        st.verify()  # every level file's sha256, through the backend
    assert any(name.startswith("chunks/") for name in installed.OPENED)  # a chunk
    with TileStore.open(text) as again:  # the store API itself asks the backends too
        assert again.location == text
    with pytest.raises(StoreError, match="demo:// needs a folder"):
        check_source("demo://")
    # The demo backend answers first: nobody else is asked about its texts.
    assert caplog.records == []
    # A text it does not claim reaches the backend raising in can_open: one warning line,
    # never an error.
    assert source_kind(str(SMALL)) == "dem"
    assert [r.getMessage() for r in caplog.records] == [RAISING_LINE]


def test_a_backend_whose_open_fails_is_reported_and_skipped(installed, caplog) -> None:
    caplog.set_level(logging.WARNING, logger="globeview.terrain.store")
    with pytest.raises(StoreError) as err:
        open_source("buggy://somewhere")
    assert str(err.value) == (
        "cannot open buggy://somewhere: store backend buggy failed (ZeroDivisionError: "
        "division by zero)"
    )
    assert any(
        r.getMessage().startswith("store backend buggy failed in open and was skipped")
        for r in caplog.records
    )


def test_without_the_package_its_scheme_is_refused_in_one_line(store: Path) -> None:
    with pytest.raises(Exception, match=r"demo:// URLs are not supported"):
        open_source(f"demo://{store}")


@pytest.mark.slow
def test_the_command_line_opens_through_the_installed_backend(site: Path, store: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(site)}
    res = subprocess.run(
        [str(GLOBEVIEW), "info", f"demo://{store}", str(SMALL)],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines()[0] == f"demo://{store}"
    assert "tile store, format" in res.stdout and SMALL.name in res.stdout
    # The DEM path reached the backend that raises in can_open: one warning line, no error.
    assert res.stderr.strip().splitlines() == [f"globeview: warning: {RAISING_LINE}"]
