"""Plugins that misbehave never take down the host (issue #13, item 10).

Every plugin here is a real throwaway distribution (package + manifest + .dist-info on
sys.path, `PluginSite`) found by the real registry; the session tests draw with a real
`GlobeSession` on a headless EGL context over the embedded terrain. What each test pins:

- plugin code raising any BaseException (SystemExit, its own KeyboardInterrupt, GeneratorExit)
  fails that plugin only; a real Ctrl-C (a SIGINT delivered while plugin code runs) is
  re-raised;
- a garbage RenderSet is caught at the host boundary (`RenderSet.validate`): the provider's
  plugin fails with a one-line reason and the frame is drawn by chunked-sse;
- a provider overrunning the time budget is disabled after N overruns ('disable' policy) or
  warned about once ('warn');
- garbage from tool hooks, layer types, settings and manifests fails that plugin only.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

import pytest

from globeview.app.testing import PluginSite, plugin_manifest
from globeview.errors import GlobeviewError
from globeview.plugins.isolation import (
    BUDGET_MS_KEY,
    BUDGET_OVERRUNS_KEY,
    BUDGET_POLICY_KEY,
    MAX_MESSAGE_CHARS,
    install_sigint_marker,
)
from globeview.plugins.registry import PluginRegistry
from globeview.plugins.settings import MemorySettings

SIZE = (96, 64)


def manifest(name: str, package: str, kind: str = "lod", attr: str = "Provider") -> str:
    return plugin_manifest(name, package, kind, attr, description="hostile test plugin")


def lod_source(body: str, prelude: str = "") -> str:
    """A provider module whose ``select`` runs ``body`` (indented 8 spaces, may use np,
    RenderSet, IndexVariant; ``self.calls`` counts calls)."""
    return (
        "import numpy as np\n"
        "from globeview.plugins.api import LodProvider\n"
        "from globeview.lod.render_set import RenderSet\n"
        "from globeview.lod.tile_indices import IndexVariant\n"
        f"{prelude}\n"
        "class Provider(LodProvider):\n"
        "    calls = 0\n"
        "    def select(self, view, terrain):\n"
        "        type(self).calls += 1\n"
        + "".join(f"        {line}\n" for line in body.strip().splitlines())
    )


def add_lod(site: PluginSite, name: str, body: str, prelude: str = "") -> None:
    package = "gvt_" + name.replace("-", "_")
    site.add(package, manifest(name, package), {"impl": lod_source(body, prelude)})


def registry(settings: MemorySettings | None = None, **kw) -> PluginRegistry:
    return PluginRegistry(settings or MemorySettings(), **kw).discover()


# -- BaseException from plugin code ---------------------------------------------------------
@pytest.mark.parametrize(
    ("raise_stmt", "error"),
    [
        ("raise SystemExit(3)", "SystemExit: 3"),
        ("raise KeyboardInterrupt('mine')", "KeyboardInterrupt: mine"),
        ("raise GeneratorExit()", "GeneratorExit"),
        ("raise Odd('odd')", "Odd: odd"),
    ],
)
def test_base_exceptions_from_select_fail_only_the_plugin(
    plugin_site: PluginSite, headless_view, raise_stmt: str, error: str
) -> None:
    add_lod(plugin_site, "exits", raise_stmt, prelude="class Odd(BaseException):\n    pass\n")
    reg = registry()
    provider = reg.lod_providers()["exits"]
    assert reg.select(provider, headless_view(0.0, 0.0, 1e7), None) is None
    rec = reg.get("exits")
    assert (rec.status, rec.error) == ("failed", error)
    assert reg.get("chunked-sse").status == "ok"


def test_systemexit_on_import_in_factory_and_in_configure(plugin_site: PluginSite) -> None:
    plugin_site.add("gvt_ximport", manifest("x-import", "gvt_ximport"), {"impl": "exit(4)\n"})
    factory = "class Provider:\n    def __init__(self, context):\n        raise SystemExit(5)\n"
    plugin_site.add("gvt_xfactory", manifest("x-factory", "gvt_xfactory"), {"impl": factory})
    configure = lod_source("return RenderSet.empty()").replace(
        "    calls = 0\n",
        "    calls = 0\n    def configure(self, values):\n        raise SystemExit('settings')\n",
    )
    plugin_site.add("gvt_xconf", manifest("x-conf", "gvt_xconf"), {"impl": configure})
    reg = registry()
    providers = reg.lod_providers()
    assert not {"x-import", "x-factory", "x-conf"} & set(providers)
    assert reg.get("x-import").error == "SystemExit: 4"
    assert reg.get("x-factory").error == "SystemExit: 5"
    assert reg.get("x-conf").error == "SystemExit: settings"
    assert "chunked-sse" in providers


def test_a_real_ctrl_c_inside_plugin_code_is_re_raised(
    plugin_site: PluginSite, headless_view
) -> None:
    # The plugin's select receives SIGINT (the user's Ctrl-C) while it runs: that is the
    # user's interrupt, not a plugin failure.
    add_lod(plugin_site, "sigint", "os.kill(os.getpid(), signal.SIGINT)\ntime.sleep(5)")
    src = (plugin_site.root / "gvt_sigint" / "impl.py").read_text()
    (plugin_site.root / "gvt_sigint" / "impl.py").write_text("import os, signal, time\n" + src)
    reg = registry()
    assert install_sigint_marker(), "the host's counting SIGINT handler is not in place"
    provider = reg.lod_providers()["sigint"]
    with pytest.raises(KeyboardInterrupt):
        reg.select(provider, headless_view(0.0, 0.0, 1e7), None)
    assert reg.get("sigint").status == "ok"


def test_huge_exception_message_is_cut_to_one_short_line(
    plugin_site: PluginSite, headless_view
) -> None:
    add_lod(plugin_site, "chatty", "raise ValueError('x' * 10**6 + '\\n' + 'y' * 10)")
    reg = registry()
    reg.select(reg.lod_providers()["chatty"], headless_view(0.0, 0.0, 1e7), None)
    err = reg.get("chatty").error
    assert err.startswith("ValueError: xxx") and len(err) <= MAX_MESSAGE_CHARS
    assert "\n" not in err


# -- garbage render sets at the host boundary (real session, real GL) -----------------------
@pytest.fixture(scope="module")
def gl(globeview_gl, globeview_terrain):
    # The plugin-author fixtures: one GL context, each test checked for GL leaks.
    from globeview.render.offscreen import OffscreenTarget

    target = OffscreenTarget(globeview_gl, SIZE)
    yield globeview_gl, target, globeview_terrain
    target.release()


#: Sessions the tests opened, released after each test (`globeview_gl` checks for leaks).
_OPEN: list = []


@pytest.fixture(autouse=True)
def _release_sessions() -> Iterator[None]:
    yield
    while _OPEN:
        _OPEN.pop().release_gl()


def session(gl, reg: PluginRegistry, lod: str):
    from globeview.app.session import GlobeSession
    from globeview.model.camera import Camera

    ctx, _, terrain = gl
    s = GlobeSession(ctx, terrain, Camera.from_lonlat(0.0, 20.0, 2.0e7), reg, lod=lod)
    _OPEN.append(s)
    return s


OK_SET = "rs = RenderSet([[0, 0, 0], [0, 1, 0]], [0, 0], [IndexVariant(stride=8, pole='both')])"

GARBAGE = {
    "level -1": ("return RenderSet([[-1, 0, 0]], [0], [IndexVariant()])", "level -1 outside"),
    "level 40": ("return RenderSet([[40, 0, 0]], [0], [IndexVariant()])", "level 40 outside"),
    "x out of range": ("return RenderSet([[2, 8, 0]], [0], [IndexVariant()])", "(2, 8, 0)"),
    "y out of range": ("return RenderSet([[2, 0, -1]], [0], [IndexVariant()])", "(2, 0, -1)"),
    "stride 3": (
        "return RenderSet([[0, 0, 0]], [0], [IndexVariant(stride=3)])",
        "stride 3 does not divide",
    ),
    "edge stride": (
        "return RenderSet([[0, 0, 0]], [0], [IndexVariant(edge_strides=(3, 1, 1, 1))])",
        "edge stride 3",
    ),
    "NaN key": (
        "return RenderSet([[np.nan, 0, 0]], [0], [IndexVariant()])",
        "ValueError: keys must be integers",
    ),
    "float keys set later": (f"{OK_SET}\nrs.keys = rs.keys * 1.5\nreturn rs", "keys must be"),
    "wrong shape set later": (
        f"{OK_SET}\nrs.keys = np.zeros((2, 2), np.int64)\nreturn rs",
        "keys must be an (N, 3) array",
    ),
    "not a RenderSet": ("return {'keys': [[0, 0, 0]]}", "returned dict, not a RenderSet"),
    "None": ("return None", "returned NoneType, not a RenderSet"),
    "10^7 keys": (
        f"{OK_SET}\nrs.keys = np.broadcast_to(np.zeros(3, np.int64), (10**7, 3))\n"
        "rs.variant_ids = np.broadcast_to(np.zeros(1, np.int64), (10**7,))\nreturn rs",
        "10000000 tiles",
    ),
    "variant id out of range": (
        "return RenderSet([[0, 0, 0]], [5], [IndexVariant()])",
        "variant id 5",
    ),
    "not a variant": ("return RenderSet([[0, 0, 0]], [0], ['stride 1'])", "not an IndexVariant"),
    "custom indices": (
        f"{OK_SET}\nrs.custom_indices = {{0: np.array([0, 1, 10**6], np.uint32)}}\nreturn rs",
        "custom_indices outside",
    ),
    "error_px NaN": (f"{OK_SET}\nrs.error_px = np.array([np.nan, 1.0])\nreturn rs", "NaN"),
    "stats garbage": (f"{OK_SET}\nrs.stats = {{'lod_ms': 'fast'}}\nreturn rs", "lod_ms"),
}


@pytest.mark.slow
@pytest.mark.gl
@pytest.mark.parametrize("case", sorted(GARBAGE))
def test_garbage_render_set_fails_the_provider_and_the_frame_falls_back(
    plugin_site: PluginSite, gl, case: str, caplog: pytest.LogCaptureFixture
) -> None:
    body, reason = GARBAGE[case]
    add_lod(plugin_site, "garbage", body)
    reg = registry()
    sess = session(gl, reg, "garbage")
    _, target, _ = gl
    with caplog.at_level(logging.WARNING, logger="globeview"):
        result = sess.render(target.fbo, SIZE)
    rec = reg.get("garbage")
    assert rec.status == "failed" and reason in rec.error, rec.error
    # The same frame is drawn by the default provider, and it stays in charge.
    assert sess.lod_name == "chunked-sse" and result.stats.lod_provider == "chunked-sse"
    assert result.stats.tiles_drawn > 0 and target.read_rgb().std() > 5
    again = sess.render(target.fbo, SIZE)
    assert again.stats.tiles_drawn > 0
    # Exactly one warning-or-worse line, naming the plugin; no traceback in it.
    lines = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(lines) == 1 and "garbage" in lines[0] and "\n" not in lines[0], lines


@pytest.mark.slow
@pytest.mark.gl
def test_valid_render_sets_of_the_builtin_providers_pass_validation(gl) -> None:
    from globeview.model.camera import Camera

    reg = registry()
    _, target, _ = gl
    views = [(0.0, 20.0, 2.0e7, 0.0, -90.0), (-71.3, 44.15, 9000.0, 0.0, -30.0)]
    for lod in ("chunked-sse", "quadtree-clod", "distance-regions", "wavelet", "fixed-level"):
        sess = session(gl, reg, lod)
        for v in views:
            sess.camera = Camera.from_lonlat(*v)
            sess.render(target.fbo, SIZE)
            assert sess.lod_name == lod, (lod, reg.get(lod).error)
    assert all(r.status == "ok" for r in reg), [(r.name, r.error) for r in reg if r.error]


# -- the time budget --------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.gl
def test_slow_provider_is_disabled_after_n_overruns(plugin_site: PluginSite, gl) -> None:
    add_lod(plugin_site, "slow", "time.sleep(0.5)\nreturn RenderSet.empty()", "import time")
    settings = MemorySettings(
        {BUDGET_MS_KEY: 100, BUDGET_OVERRUNS_KEY: 3, BUDGET_POLICY_KEY: "disable"}
    )
    reg = registry(settings)
    sess = session(gl, reg, "slow")
    _, target, _ = gl
    for _ in range(3):
        assert reg.get("slow").status == "ok"
        sess.render(target.fbo, SIZE)
    rec = reg.get("slow")
    assert rec.status == "failed" and rec.error.startswith("PluginTimeout: select() took")
    assert "over the 100 ms budget" in rec.error and "3 calls in a row" in rec.error
    calls = type(next(iter(reg._owners.values()))[1]).calls
    result = sess.render(target.fbo, SIZE)
    assert result.stats.lod_provider == "chunked-sse" and result.stats.tiles_drawn > 0
    assert type(next(iter(reg._owners.values()))[1]).calls == calls  # not called again


def test_budget_overruns_must_be_consecutive(plugin_site: PluginSite, headless_view) -> None:
    add_lod(
        plugin_site,
        "sometimes",
        "time.sleep(0.25 if type(self).calls % 2 else 0.0)\nreturn RenderSet.empty()",
        "import time",
    )
    reg = registry(
        MemorySettings({BUDGET_MS_KEY: 100, BUDGET_OVERRUNS_KEY: 2}), budget_policy="disable"
    )
    provider = reg.lod_providers()["sometimes"]
    for _ in range(4):
        assert reg.select(provider, headless_view(0.0, 0.0, 1e7), None) is not None
    assert reg.get("sometimes").status == "ok"


@pytest.mark.slow
def test_headless_budget_policy_warns_once_and_keeps_the_plugin(
    plugin_site: PluginSite, headless_view, caplog: pytest.LogCaptureFixture
) -> None:
    add_lod(plugin_site, "sluggish", "time.sleep(0.15)\nreturn RenderSet.empty()", "import time")
    # policy: the headless default, warn
    reg = registry(MemorySettings({BUDGET_MS_KEY: 100, BUDGET_OVERRUNS_KEY: 3}))
    assert reg.budget.policy == "warn"
    provider = reg.lod_providers()["sluggish"]
    view = headless_view(0.0, 0.0, 1e7)
    with caplog.at_level(logging.WARNING, logger="globeview.plugins"):
        for _ in range(2):  # fewer overruns than the limit: no verdict yet
            assert reg.select(provider, view, None) is not None
        assert caplog.records == []
        for _ in range(4):
            assert reg.select(provider, view, None) is not None
    assert reg.get("sluggish").status == "ok"
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "sluggish" in lines[0] and "100 ms" in lines[0]
    assert "3 calls in a row" in lines[0]


def test_budget_settings_of_the_wrong_type_are_ignored() -> None:
    reg = PluginRegistry(
        MemorySettings({BUDGET_MS_KEY: "fast", BUDGET_OVERRUNS_KEY: -2, BUDGET_POLICY_KEY: 7})
    )
    assert (reg.budget.ms, reg.budget.overruns, reg.budget.policy) == (1000.0, 5, "warn")


# -- other hooks: tools, layer types ------------------------------------------------------------
TOOL_SRC = """
import numpy as np
from globeview.plugins.api import Tool

class BadTool(Tool):
    def displacement_glsl(self):
        return "vec3 gv_displace(vec3 p, vec3 up, float h, vec3 c) {{ return p; }}"

    def displacement_numpy(self, points):
        {body}
"""


@pytest.mark.slow
@pytest.mark.gl
@pytest.mark.parametrize(
    ("body", "reason"),
    [
        ("return np.full_like(points, np.nan)", "NaN or infinite"),
        ("return points[:1]", "returned shape"),
        ("return 'moved'", "returned something else"),
        ("raise SystemExit(9)", "SystemExit: 9"),
    ],
)
def test_garbage_displacement_fails_the_tool_not_the_provider(
    plugin_site: PluginSite, gl, body: str, reason: str
) -> None:
    plugin_site.add(
        "gvt_badwarp",
        manifest("bad-warp", "gvt_badwarp", "tool", "BadTool"),
        {"impl": TOOL_SRC.format(body=body)},
    )
    reg = registry()
    sess = session(gl, reg, "chunked-sse")
    sess.activate_tool("bad-warp")
    _, target, _ = gl
    result = sess.render(target.fbo, SIZE)
    rec = reg.get("bad-warp")
    assert rec.status == "failed" and reason in rec.error, rec.error
    assert reg.get("chunked-sse").status == "ok" and sess.lod_name == "chunked-sse"
    assert result.stats.tiles_drawn > 0
    assert sess.tool() is None
    assert sess.render(target.fbo, SIZE).stats.tiles_drawn > 0


def _geojson_lines(path: Path) -> Path:
    path.write_text(
        '{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {}, '
        '"geometry": {"type": "LineString", "coordinates": [[0, 0], [10, 10]]}}]}'
    )
    return path


@pytest.mark.slow
@pytest.mark.gl
@pytest.mark.parametrize(
    ("open_body", "reason"),
    [
        ("return None", "open() returned NoneType, not a layer"),
        ("raise SystemExit(2)", "SystemExit: 2"),
        ("return 42", "open() returned int, not a layer"),
    ],
)
def test_layer_type_returning_garbage_fails_that_plugin_only(
    plugin_site: PluginSite, gl, tmp_path: Path, open_body: str, reason: str
) -> None:
    src = (
        "class Vector:\n"
        "    name = 'vector'\n    label = 'bad vectors'\n    extensions = ('.geojson',)\n"
        "    def __init__(self, context):\n        pass\n"
        f"    def open(self, path, **style):\n        {open_body}\n"
    )
    plugin_site.add(
        "gvt_badlayer", manifest("vector", "gvt_badlayer", "layer", "Vector"), {"impl": src}
    )
    reg = registry()
    reg.disable("layers")  # so the hostile plugin is the one that opens vector files
    sess = session(gl, reg, "chunked-sse")
    with pytest.raises(GlobeviewError) as info:
        sess.add_overlay(str(_geojson_lines(tmp_path / "lines.geojson")))
    assert "\n" not in str(info.value) and "vector" in str(info.value)
    rec = reg.get("vector")
    assert rec.status == "failed" and reason in rec.error, rec.error
    _, target, _ = gl
    assert sess.render(target.fbo, SIZE).stats.tiles_drawn > 0


# -- settings and manifests ---------------------------------------------------------------------
def test_stored_setting_values_that_are_not_numbers_do_not_break_a_plugin() -> None:
    from globeview.plugins.api import Setting, resolve_settings

    s = Setting("k", "int", 4, 1, 8)
    for bad in (float("nan"), float("inf"), 1e400, "1e999", [1], {"a": 1}, None, True):
        assert resolve_settings([s], {"k": bad}) == {"k": 4}, bad
    assert resolve_settings([s], "not a dict") == {"k": 4}  # type: ignore[arg-type]


HOSTILE_MANIFESTS = {
    "huge name": ('name = "' + "a" * 50_000 + '"\n', "characters (at most 200)"),
    "name not a string": ('name = 5\nversion = "1"\n', "must be a string, got int"),
    "kinds a number": (
        'name = "x"\nversion = "1"\ndescription = "d"\napi_version = "1.0"\nkinds = 3\n',
        "field 'kinds' must be a non-empty list",
    ),
    "kinds of tables": (
        'name = "x"\nversion = "1"\ndescription = "d"\napi_version = "1.0"\nkinds = [{a = 1}]\n',
        "unknown kind {'a': 1}",
    ),
    "contributions a string": (
        'name = "x"\nversion = "1"\ndescription = "d"\napi_version = "1.0"\nkinds = ["lod"]\n'
        'contributions = "all"\n',
        "non-empty array of tables",
    ),
    "deeply nested": ("x = " + "[" * 20_000 + "]" * 20_000 + "\n", "not valid TOML"),
    "10 MB": ('name = "x"\ndescription = "' + "d" * 10_000_000 + '"\n', "larger than 64 KiB"),
}


@pytest.mark.parametrize("case", sorted(HOSTILE_MANIFESTS))
def test_hostile_manifest_fails_that_plugin_with_one_short_line(
    plugin_site: PluginSite, case: str
) -> None:
    text, reason = HOSTILE_MANIFESTS[case]
    plugin_site.add("gvt_hostile", "", entry_name="hostile")
    (plugin_site.root / "gvt_hostile" / "globeview.toml").write_text(text)
    reg = registry()
    rec = reg.get("hostile")
    assert rec.status == "failed" and reason in rec.error, rec.error[:200]
    assert len(rec.error) <= MAX_MESSAGE_CHARS and "\n" not in rec.error
    assert reg.get("chunked-sse").status == "ok"


def test_non_utf8_manifest_fails_that_plugin(plugin_site: PluginSite) -> None:
    plugin_site.add("gvt_latin1", "", entry_name="latin1")
    (plugin_site.root / "gvt_latin1" / "globeview.toml").write_bytes(
        b'name = "latin1"\ndescription = "caf\xe9 \xff\xfe"\n'
    )
    reg = registry()
    assert "not UTF-8" in reg.get("latin1").error
    assert reg.get("chunked-sse").status == "ok"


def test_a_distribution_with_unreadable_metadata_hides_no_other_plugin(
    plugin_site: PluginSite,
) -> None:
    plugin_site.add("gvt_fine", manifest("fine", "gvt_fine"), {"impl": lod_source("return 1")})
    broken = plugin_site.root / "gvt_broken-1.0.dist-info"
    broken.mkdir()
    (broken / "METADATA").write_text("Metadata-Version: 2.1\nName: gvt-broken\nVersion: 1.0\n")
    (broken / "entry_points.txt").write_bytes(b"[globeview.plugins]\nbroken = \xff\xfe:x.toml\n")
    garbled = plugin_site.root / "gvt_garbled-1.0.dist-info"
    garbled.mkdir()
    (garbled / "METADATA").write_bytes(b"\xff\xfe\x00")
    (garbled / "entry_points.txt").write_text("[globeview.plugins]\ngarbled = json:x.toml\n")
    reg = registry()
    assert reg.get("fine").status == "ok" and reg.get("chunked-sse").status == "ok"
    assert "broken" not in reg
    assert reg.get("garbled").status == "failed"  # its manifest is not in 'json'


@pytest.mark.slow
def test_requested_provider_of_a_failed_plugin_is_named_in_the_error(
    plugin_site: PluginSite, gl
) -> None:
    plugin_site.add("gvt_nover", "", entry_name="no-version")
    (plugin_site.root / "gvt_nover" / "globeview.toml").write_text('name = "no-version"\n')
    reg = registry()
    with pytest.raises(GlobeviewError, match=r"plugin no-version failed: .*'version'"):
        session(gl, reg, "no-version")


def test_configure_raising_systemexit_fails_the_plugin_and_stale_configure_is_ignored(
    plugin_site: PluginSite,
) -> None:
    src = lod_source("return RenderSet.empty()").replace(
        "    calls = 0\n",
        "    calls = 0\n"
        "    def configure(self, values):\n"
        "        if values.get('boom'):\n"
        "            raise SystemExit('configure')\n",
    )
    plugin_site.add("gvt_conf2", manifest("conf2", "gvt_conf2"), {"impl": src})
    reg = registry()
    provider = reg.lod_providers()["conf2"]
    reg.configure(provider, {"boom": True})
    assert reg.get("conf2").error == "SystemExit: configure"
    reg.configure(provider, {"boom": True})  # a stale reference: nothing happens
    assert reg.get("chunked-sse").status == "ok"


def test_render_set_subclass_whose_attributes_raise_fails_the_plugin(
    plugin_site: PluginSite, headless_view
) -> None:
    prelude = (
        "class Sneaky(RenderSet):\n"
        "    @property\n"
        "    def custom_indices(self):\n"
        "        raise SystemExit('gotcha')\n"
        "    @custom_indices.setter\n"
        "    def custom_indices(self, value):\n"
        "        pass\n"
    )
    add_lod(plugin_site, "sneaky", "return Sneaky([[0, 0, 0]], [0], [IndexVariant()])", prelude)
    reg = registry()
    provider = reg.lod_providers()["sneaky"]
    check = lambda rs: rs.validate(65, None)  # noqa: E731
    assert reg.select(provider, headless_view(0.0, 0.0, 1e7), None, check=check) is None
    assert reg.get("sneaky").error == "SystemExit: gotcha"


@pytest.mark.slow
@pytest.mark.gl
def test_unknown_provider_name_error_is_short(gl) -> None:
    with pytest.raises(GlobeviewError) as info:
        session(gl, registry(), "x" * 100_000)
    assert len(str(info.value)) < 300 and "no enabled LOD provider" in str(info.value)


def test_failure_traceback_goes_to_the_log_file_the_line_names(
    plugin_site: PluginSite,
    headless_view,
    _failure_log_in_tmp: Path,  # noqa: PT019  its value, the log file, is read below
    caplog,
) -> None:
    add_lod(plugin_site, "logged", "raise SystemExit('bye')")
    reg = registry()
    with caplog.at_level(logging.WARNING, logger="globeview.plugins"):
        reg.select(reg.lod_providers()["logged"], headless_view(0.0, 0.0, 1e7), None)
    (line,) = [r.getMessage() for r in caplog.records]
    assert line.endswith(f"(details in {_failure_log_in_tmp})")
    text = _failure_log_in_tmp.read_text()
    assert "plugin logged failed and was disabled:" in text
    assert "Traceback (most recent call last)" in text and "SystemExit: bye" in text


def test_an_unwritable_log_costs_only_the_details_suffix(
    plugin_site: PluginSite, headless_view, monkeypatch, caplog
) -> None:
    from globeview.plugins import isolation

    blocker = plugin_site.root / "not-a-dir"
    blocker.write_text("")
    monkeypatch.setattr(isolation, "failure_log_path", lambda: blocker / "globeview.log")
    add_lod(plugin_site, "unlogged", "raise ValueError('nope')")
    reg = registry()
    with caplog.at_level(logging.WARNING, logger="globeview.plugins"):
        reg.select(reg.lod_providers()["unlogged"], headless_view(0.0, 0.0, 1e7), None)
    lines = [r.getMessage() for r in caplog.records]
    assert lines == ["plugin unlogged failed and was disabled: ValueError: nope"]


def test_slow_tool_event_handler_is_disabled_under_the_disable_policy(
    plugin_site: PluginSite,
) -> None:
    from globeview.plugins.api import PointerEvent

    src = (
        "import time\nfrom globeview.plugins.api import Tool\n"
        "class SlowTool(Tool):\n"
        "    def on_mouse(self, event):\n"
        "        time.sleep(0.15)\n"
        "        return True\n"
    )
    plugin_site.add(
        "gvt_slowtool", manifest("slow-tool", "gvt_slowtool", "tool", "SlowTool"), {"impl": src}
    )
    reg = registry(
        MemorySettings({BUDGET_MS_KEY: 100, BUDGET_OVERRUNS_KEY: 2}), budget_policy="disable"
    )
    tool = reg.tools()["slow-tool"]
    event = PointerEvent(1, 2, "move")
    assert reg.invoke(tool, "on_mouse", event, default=False) is True
    assert reg.invoke(tool, "on_mouse", event, default=False) is True
    rec = reg.get("slow-tool")
    assert rec.status == "failed" and rec.error.startswith("PluginTimeout: on_mouse() took")
    assert reg.invoke(tool, "on_mouse", event, default=False) is False  # not called again
