"""Where the package keeps its files: a checkout's data folder, an install's cache folder (``awr_denoise._places``)."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import awr_denoise
from awr_denoise import _places

_REPOSITORY = Path(awr_denoise.__file__).resolve().parents[1]


def _in_the_install(site: Path, code: str, cache: Path, cwd: Path) -> dict:
    """The dict ``result`` that ``code`` makes in a Python importing the package from ``site``."""
    done = subprocess.run([sys.executable, "-c", f"import json\n{code}\nprint(json.dumps(result))"],
                          env={**os.environ, "PYTHONPATH": str(site), "XDG_CACHE_HOME": str(cache)}, cwd=cwd,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_a_checkout_keeps_its_files_in_its_data_folder():
    if not (_REPOSITORY / "pyproject.toml").is_file():
        pytest.skip("the tests run against an installed package, not a checkout")
    assert _places.checkout_data() == _REPOSITORY / "data"
    assert _places.shown_path(_REPOSITORY / "data" / "references" / "default.exr") == "data/references/default.exr"
    assert _places.shown_path("/elsewhere/x.exr") == "/elsewhere/x.exr"


def test_an_install_keeps_them_in_the_cache_folder_whatever_data_folder_lies_beside_it(tmp_path, wheel_layout):
    """In an install the package's parent is site-packages, whose ``data`` folder (another package's) was taken for a
    checkout's: the references were written there, another package's ``references/default.exr`` read as the
    reference, and a read-only site-packages failed every demo (an attack pass)."""
    (wheel_layout / "data" / "references").mkdir(parents=True)
    cache = tmp_path / "cache"
    found = _in_the_install(wheel_layout, "from awr_denoise import _places\nfrom awr_denoise.bench import mitsuba\n"
                            "result = {'data': str(_places.checkout_data()), "
                            "'mitsuba': str(mitsuba.default_reference_dir())}", cache, tmp_path)
    assert found == {"data": "None", "mitsuba": str(cache / "awr-denoise" / "mitsuba")}
    if importlib.util.find_spec("embreex") is None:
        return
    found = _in_the_install(wheel_layout, "from awr_denoise.tracer import reference\n"
                            "result = {'references': str(reference.reference_dir())}", cache, tmp_path)
    assert found == {"references": str(cache / "awr-denoise" / "references")}


@pytest.mark.parametrize(("value", "expected"), [("{tmp}/xdg", "{tmp}/xdg/awr-denoise"),
                                                 ("", "{home}/.cache/awr-denoise"),
                                                 ("relative/xdg", "{home}/.cache/awr-denoise")])
def test_the_cache_folder_follows_xdg_cache_home_where_it_is_absolute(monkeypatch, tmp_path, value, expected):
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("XDG_CACHE_HOME", value.format(tmp=tmp_path))
    assert _places.cache_folder() == Path(expected.format(tmp=tmp_path, home=tmp_path / "home"))


def test_writing_the_checkouts_files_needs_a_folder_in_an_install(tmp_path, wheel_layout):
    pytest.importorskip("embreex")
    code = ("import awr_denoise.tracer.scenes as s, sys\ntry:\n    s.write_scene_files()\nexcept ValueError as exc:\n"
            "    print(exc)\nprint(len(s.write_scene_files(sys.argv[1])))")
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path / "scenes")],
                          env={**os.environ, "PYTHONPATH": str(wheel_layout)}, cwd=tmp_path, capture_output=True,
                          text=True, timeout=120)
    assert done.stdout.splitlines() == ["directory: give the folder to write; the default, data/scenes, is a "
                                        "checkout's", str(len(list((tmp_path / "scenes").glob("*.json"))))]
    assert not (wheel_layout / "data").exists()


def test_without_a_home_folder_the_cache_folder_names_the_variable(monkeypatch):
    """A container's user without a passwd entry has no home: ``Path.home()``'s RuntimeError was an internal error, at
    the benchmark's import (a review of the change)."""
    def no_home():
        raise RuntimeError("Could not determine home directory.")

    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.setattr(Path, "home", staticmethod(no_home))
    with pytest.raises(ValueError, match=r"^XDG_CACHE_HOME: unset, and there is no home folder"):
        _places.cache_folder()
    monkeypatch.setenv("XDG_CACHE_HOME", "/cache")
    assert _places.cache_folder() == Path("/cache/awr-denoise")


def test_a_path_through_a_link_in_the_checkout_is_recorded_by_its_name_there(monkeypatch, tmp_path):
    """A checkout whose ``data/references`` links to another disk recorded that disk's absolute path."""
    root, elsewhere = tmp_path / "checkout", tmp_path / "disk" / "refs"
    elsewhere.mkdir(parents=True)
    (root / "data").mkdir(parents=True)
    (root / "data" / "references").symlink_to(elsewhere)
    monkeypatch.setattr(_places, "_checkout_root", lambda: root)
    assert _places.shown_path(root / "data" / "references" / "default.exr") == "data/references/default.exr"
    assert _places.shown_path(elsewhere / "default.exr") == str(elsewhere / "default.exr")


def test_a_name_with_dot_dot_is_recorded_as_the_file_it_reaches(monkeypatch, tmp_path):
    """A name that steps up (``..``) out of a linked folder reaches the folder beside the link's target, not the
    checkout's: it is recorded as given."""
    root, elsewhere = tmp_path / "checkout", tmp_path / "disk" / "refs"
    elsewhere.mkdir(parents=True)
    (root / "data").mkdir(parents=True)
    (root / "data" / "references").symlink_to(elsewhere)
    monkeypatch.setattr(_places, "_checkout_root", lambda: root)
    path = root / "data" / "references" / ".." / "x.exr"
    assert _places.shown_path(path) == str(path)
