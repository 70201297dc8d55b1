"""The project file's schema without a globe (`globeview.model.project`): the example in
docs/projects.md reads, a project survives writing and reading unchanged, hostile text is
one `ProjectError` line, and bookmarks keep unique names with one event per change."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from globeview.model.bookmarks import Bookmarks
from globeview.model.project import ProjectError, parse_project, project_text, resolve_path

DOC = Path(__file__).resolve().parents[2] / "docs" / "projects.md"


def test_the_documented_example_reads():
    text = re.search(r"```toml\n(.*?)```", DOC.read_text(), re.S)
    assert text is not None
    project = parse_project(text.group(1), "docs/projects.md")
    assert [d.kind for d in project.dems] == ["path", "embedded"]
    assert project.tool is not None and project.tool.points == ((-71.5, 44.3), (-71.1, 44.3))
    assert project.overlays[0].style["color"] == (1.0, 0.9, 0.2, 1.0)
    assert project.overlays[0].open == {}
    assert project.overlays[1].open == {
        "layer": "trails",
        "color_by": "kind",
        "label": "name",
        "width_px": 3.0,
    }
    assert project.bookmarks[0].name == "washington"
    assert [t["name"] for t in project.tours] == ["washington"]
    from globeview.app.project import project_tour

    tour, problems = project_tour(project)
    assert problems == [] and tour.name == "washington" and tour.duration == 6.0


def test_write_then_read_is_the_same_project():
    text = re.search(r"```toml\n(.*?)```", DOC.read_text(), re.S)
    assert text is not None
    project = parse_project(text.group(1))
    assert parse_project(project_text(project)) == project


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("schema = true\n", "schema must be a whole number"),
        ("schema = 0\n", "from an unknown version; this globeview reads schema 1"),
        ("schema = 1\n", "no [camera] table"),
        ('schema = 1\n[camera]\nlon = 0.0\nlat = 0.0\nheight = "high"\n', "camera.height must"),
        ("schema = 1\n[camera]\nlon = 0.0\nlat = 0.0\nheight = 1.0\nfov = 0.0\n", "camera.fov"),
        (
            'schema = 1\n[camera]\nlon = 0.0\nlat = 0.0\nheight = 1.0\n[[dems]]\npath = "a"\n'
            'url = "https://x/y"\n',
            "dems[0] needs exactly one of path, url, embedded",
        ),
        (
            "schema = 1\n[camera]\nlon = 0.0\nlat = 0.0\nheight = 1.0\n[[bookmarks]]\n"
            'name = "a"\nlon = 0.0\nlat = 0.0\nheight = 1.0\n[[bookmarks]]\nname = "a"\n'
            "lon = 0.0\nlat = 0.0\nheight = 1.0\n",
            "is used twice",
        ),
        (b"\xff\xfe\x00schema", "not TOML"),
        (
            'schema = 1\n[camera]\nlon = 0.0\nlat = 0.0\nheight = 1.0\n[[overlays]]\npath = "a"\n'
            "open = { width_px = { x = 1 } }\n",
            "overlays[0].open.width_px must be text, true/false, a number or a list of those",
        ),
        (
            'schema = 1\n[camera]\nlon = 0.0\nlat = 0.0\nheight = 1.0\n[[overlays]]\npath = "a"\n'
            "open = 3\n",
            "overlays[0].open must be a table of at most 32 options",
        ),
    ],
)
def test_hostile_text_is_one_line(text, message):
    with pytest.raises(ProjectError, match=re.escape(message)) as info:
        parse_project(text, "p.toml")
    assert "\n" not in str(info.value)


def test_paths_resolve_relative_to_the_project(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "x.tif").write_bytes(b"")
    assert resolve_path(tmp_path / "a", "x.tif") == tmp_path / "a" / "x.tif"
    assert resolve_path(tmp_path / "a", "../a/x.tif").resolve() == tmp_path / "a" / "x.tif"
    for text, message in [
        ("/etc/hostname", "is an absolute path"),
        ("~/x.tif", "is an absolute path"),
        ("y.tif", "no such file"),
        (".", "is not a file"),
    ]:
        with pytest.raises(ValueError, match=re.escape(message)):
            resolve_path(tmp_path / "a", text)
    assert resolve_path(tmp_path, "a", want="any") == tmp_path / "a"  # a store folder


def test_bookmarks_names_are_unique_and_each_change_is_one_event():
    marks = Bookmarks()
    events = []
    marks.changed.connect(lambda: events.append(1))
    marks.add("a", (0.0, 0.0, 100.0, 0.0, -90.0, 0.0))
    marks.add("b", (1.0, 1.0, 100.0, 0.0, -90.0, 0.0))
    marks.add("a", (0.0, 0.0, 100.0, 0.0, -90.0, 0.0))  # the same: no event
    marks.add("a", (2.0, 0.0, 100.0, 0.0, -90.0, 0.0))  # replaced in place
    assert marks.names == ["a", "b"] and marks["a"].pose[0] == 2.0 and len(events) == 3
    marks.remove("b")
    assert marks.names == ["a"] and len(events) == 4
    with pytest.raises(ValueError, match="latitude"):
        marks.add("c", (0.0, 95.0, 100.0, 0.0, -90.0, 0.0))
    with pytest.raises(KeyError):
        marks.remove("zzz")
