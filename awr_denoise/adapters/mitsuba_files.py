"""The files a Mitsuba 3 XML scene reads besides itself, found without loading it.

``awr render --renderer mitsuba SCENE.xml`` checks them with its other inputs before Mitsuba runs:
an output must never replace a texture, and a FIFO among them would block Mitsuba's loader in a
thread no signal reaches. Mitsuba reads a file where

- an element has a ``filename`` attribute (``<include filename=...>``, ``<spectrum
  filename=...>``) or a ``<string name="filename" value=...>`` child (textures, meshes,
  environment maps, volumes);
- a value holds ``$name``: the parameter's ``<default name=... value=...>`` when the render gives
  none (``awr render`` gives none);
- a relative name is looked up in the ``<path value=...>`` folders (the last declared first),
  beside the scene file, then in the working folder, as Mitsuba's file resolver does.

The scene file may have any name: Mitsuba loads ``scene.txt`` as XML too.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

from .mitsuba_scenes import SCENE_NAMES

__all__ = ["scene_files"]

_PARAMETER = re.compile(r"\$(\w+)")


def scene_files(scene: Any) -> list[tuple[str, Path]]:
    """The files a Mitsuba XML scene reads besides itself, as ``(what, path)``.

    Included XML files are followed. A name whose ``$`` parameter has no default is left out
    (Mitsuba refuses the scene then); a bundled scene name or a scene dict reads none.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> folder = Path(tempfile.mkdtemp())
    >>> _ = (folder / "scene.xml").write_text(
    ...     '<scene version="3.0.0"><default name="mesh" value="bunny.obj"/>'
    ...     '<shape type="obj"><string name="filename" value="$mesh"/></shape>'
    ...     '<spectrum name="eta" filename="glass.spd"/></scene>')
    >>> [(what, path.name) for what, path in scene_files(folder / "scene.xml")]
    [('filename bunny.obj', 'bunny.obj'), ('filename glass.spd', 'glass.spd')]
    """
    if not isinstance(scene, (str, os.PathLike)):
        return []
    first = Path(scene)
    if isinstance(scene, str) and scene in SCENE_NAMES and not os.path.lexists(first):
        return []  # a bundled scene, built from a dict
    files: list[tuple[str, Path]] = []
    defaults: dict[str, str] = {}
    folders: list[Path] = []
    pending, seen = [first], set()
    while pending:
        path = pending.pop()
        if path.resolve() in seen or not path.is_file():  # not a regular file: the caller refuses it
            continue
        seen.add(path.resolve())
        try:
            root = ElementTree.parse(path).getroot()
        except (ElementTree.ParseError, OSError) as exc:
            raise ValueError(f"{path}: not a readable Mitsuba XML scene ({exc})") from None
        for element in root.iter("default"):
            name, value = element.get("name"), element.get("value")
            if name and value is not None:
                defaults.setdefault(name, value)  # the first definition counts, as in Mitsuba
        for element in root.iter():
            if element.tag == "path" and element.get("value"):
                folder = _substituted(element.get("value", ""), defaults)
                if folder is not None:
                    folders.append(Path(folder) if Path(folder).is_absolute() else path.parent / folder)
                continue
            given = element.get("filename")
            if given is None and element.tag == "string" and element.get("name") == "filename":
                given = element.get("value")
            value = _substituted(given or "", defaults)
            if not value:
                continue
            file = _located(value, path.parent, first.parent, folders)
            files.append((f"{'include' if element.tag == 'include' else 'filename'} {value}", file))
            if element.tag == "include":
                pending.append(file)
    return files


def _substituted(value: str, defaults: dict[str, str]) -> str | None:
    """``value`` with its ``$name`` parameters replaced by their defaults; None if one has none."""
    missing = [name for name in _PARAMETER.findall(value) if name not in defaults]
    if missing:
        return None
    return _PARAMETER.sub(lambda m: defaults[m.group(1)], value)


def _located(value: str, here: Path, scene_folder: Path, folders: list[Path]) -> Path:
    """Where Mitsuba's file resolver finds ``value``: search folders, the scene's folder, the
    working folder; a name found nowhere is reported beside the file that names it."""
    name = Path(value)
    if name.is_absolute():
        return name
    for folder in [*reversed(folders), here, scene_folder, Path.cwd()]:
        if os.path.lexists(folder / name):
            return folder / name
    return here / name
