"""The files a Mitsuba 3 XML scene reads besides itself, found without loading it.

``awr render --renderer mitsuba SCENE.xml`` checks them with its other inputs before Mitsuba runs:
an output must never replace a texture, and a FIFO among them would block Mitsuba's loader in a
thread no signal reaches. The walk follows Mitsuba 3's parser (``src/core/parser.cpp``) in
document order, includes where they stand:

- every attribute's ``$name`` is replaced by the defined parameter whose name is the longest
  match (``$t_x.exr`` with only ``t`` defined reads ``<t>_x.exr``), ``\\$`` is a literal ``$``,
  and a ``<default name=... value=...>`` defines a parameter from that point on, in any file,
  unless the render or an earlier ``<default>`` did (an undefined one stops the parse);
- an ``<include filename=...>`` or a ``filename`` attribute (``<spectrum filename=...>``) is
  read while parsing: looked up beside the file that names it, then in the folders known there;
- a plugin's ``<string name="filename" value=...>`` (textures, meshes, environment maps) is read
  after parsing, with the main scene's resolver only: its ``<path>`` folders (the last declared
  first), the scene's folder, the working folder. An included file's folder and its ``<path>``
  folders are not searched then: a texture named in ``sub/part.xml`` is found beside the scene.

The scene file may have any name: Mitsuba loads ``scene.txt`` as XML too.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

from .mitsuba_scenes import SCENE_NAMES

__all__ = ["scene_files"]

# Mitsuba's ParserConfig.max_include_depth: deeper includes are refused, so never followed.
_MAX_DEPTH = 15


class _Stop(Exception):
    """Mitsuba refuses the scene at this point: nothing after it is read."""


class _Walk:
    """What one walk over a scene gathers: its parameters (``$name``, value; the longest name
    first), the files named with the folders they are looked up in, the main resolver's folders."""

    def __init__(self, scene: Path, params: Mapping[str, Any]) -> None:
        self.params: list[tuple[str, str]] = []
        for name, value in params.items():
            self.define(str(name), str(value))
        self.named: list[tuple[str, str, list[Path]]] = []
        # mi.load_file's resolver: the scene's folder before the working folder (Mitsuba's default).
        self.main = [scene.parent, Path()]

    def define(self, name: str, value: str) -> None:
        """Define ``$name`` unless it is; equal lengths keep their order, as Mitsuba's insert."""
        key = "$" + name
        if any(known == key for known, _ in self.params):
            return
        at = next((i for i, (known, _) in enumerate(self.params) if len(key) > len(known)), len(self.params))
        self.params.insert(at, (key, value))

    def substituted(self, value: str) -> str:
        """``value`` as Mitsuba's ``substitute_parameters`` leaves it; :class:`_Stop` on an
        undefined parameter."""
        for key, replacement in self.params:
            pos = value.find(key)
            while pos >= 0:
                if pos > 0 and value[pos - 1] == "\\":
                    pos = value.find(key, pos + len(key))
                else:
                    value = value[:pos] + replacement + value[pos + len(key):]
                    pos = value.find(key, pos + len(replacement))
        if any(value[i] == "$" and (i == 0 or value[i - 1] != "\\") for i in range(len(value))):
            raise _Stop
        return value.replace("\\$", "$")


def scene_files(scene: Any, params: Mapping[str, Any] | None = None) -> list[tuple[str, Path]]:
    """The files a Mitsuba XML scene reads besides itself, as ``(what, path)``, in document order.

    Each is where Mitsuba 3's file resolver finds it (see the module's notes); a name found
    nowhere is given as Mitsuba opens it then, from the working folder. Where Mitsuba would
    refuse the scene (an undefined parameter, a missing include), the files read before that
    point are listed. A bundled scene name or a scene dict reads none.

    Parameters
    ----------
    scene
        The scene file (any name), a bundled scene name or a scene dict.
    params
        The render's parameters, as given to ``mi.load_file(scene, **params)``; they take
        precedence over the scene's ``<default>`` values.

    Raises
    ------
    ValueError
        A scene or included file that is not XML.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> folder = Path(tempfile.mkdtemp())
    >>> _ = (folder / "scene.xml").write_text(
    ...     '<scene version="3.0.0"><default name="mesh" value="bunny"/>'
    ...     '<shape type="obj"><string name="filename" value="$mesh_lod0.obj"/></shape>'
    ...     '<spectrum name="eta" filename="glass.spd"/></scene>')
    >>> [(what, path.name) for what, path in scene_files(folder / "scene.xml")]
    [('filename bunny_lod0.obj', 'bunny_lod0.obj'), ('filename glass.spd', 'glass.spd')]
    >>> [path.name for _, path in scene_files(folder / "scene.xml", params={"mesh": "cube"})]
    ['cube_lod0.obj', 'glass.spd']
    """
    if not isinstance(scene, (str, os.PathLike)):
        return []
    first = Path(scene)
    if isinstance(scene, str) and scene in SCENE_NAMES and not os.path.lexists(first):
        return []  # a bundled scene, built from a dict
    walk = _Walk(first, params or {})
    try:
        _visit_file(walk, first, walk.main, 0)
    except _Stop:
        # Parsing stopped: nothing is instantiated, so only the files parsing reads are read.
        walk.named = [entry for entry in walk.named if entry[2] is not walk.main]
    return [(what, _resolved(value, folders)) for what, value, folders in walk.named]


def _visit_file(walk: _Walk, path: Path, folders: list[Path], depth: int) -> None:
    """Walk one XML file (the scene or an include) with the resolver's ``folders`` of that point."""
    if not path.is_file():  # missing or special: the caller refuses it, and it is never opened
        raise _Stop
    _visit(walk, _parsed(path), path, folders, depth, 0)


def _visit(walk: _Walk, element: ElementTree.Element, path: Path, folders: list[Path], depth: int,
           level: int) -> None:
    """One element as Mitsuba's ``parse_xml_node`` treats it, then its children (``level`` 0 is
    the file's root; ``<path>`` may stand at level 1 only)."""
    values = {key: walk.substituted(value) for key, value in element.attrib.items()}
    tag, filename = element.tag, values.get("filename")
    if tag == "default" and values.get("name"):
        walk.define(values["name"], values.get("value", ""))
    elif tag == "path" and "value" in values:
        if level != 1:
            raise _Stop  # "<path> can only be child of root"
        folder = Path(values["value"])
        if not folder.is_absolute():
            beside = path.parent / folder
            folder = beside if os.path.exists(beside) else _resolved(values["value"], folders)
        folders.insert(0, folder)
    elif tag == "include" and filename is not None:
        scope = [path.parent, *folders]  # the including file's folder first, for this include only
        walk.named.append((f"include {filename}", filename, scope))
        if depth + 1 >= _MAX_DEPTH:
            raise _Stop
        _visit_file(walk, _resolved(filename, scope), scope, depth + 1)
    elif filename is not None:
        walk.named.append((f"filename {filename}", filename, list(folders)))  # read while parsing
    elif tag == "string" and values.get("name") == "filename" and values.get("value"):
        walk.named.append((f"filename {values['value']}", values["value"], walk.main))  # read after
    for child in element:
        _visit(walk, child, path, folders, depth, level + 1)


def _parsed(path: Path) -> ElementTree.Element:
    """The root element of ``path``; a byte that is not UTF-8 (in a comment, say) is replaced and
    the file read again, as pugixml, which does not check the encoding, loads it."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ValueError(f"{path}: not a readable Mitsuba XML scene ({exc.strerror})") from None
    try:
        return ElementTree.fromstring(data)
    except ElementTree.ParseError as exc:
        try:
            return ElementTree.fromstring(data.decode("utf-8", "replace"))
        except ElementTree.ParseError:
            raise ValueError(f"{path}: not a readable Mitsuba XML scene ({exc})") from None


def _resolved(value: str, folders: list[Path]) -> Path:
    """Where Mitsuba's ``FileResolver.resolve`` finds ``value``: the first of ``folders`` holding
    it (``fs::exists``: links followed), else the name as given."""
    name = Path(value)
    if not name.is_absolute():
        for folder in folders:
            if os.path.exists(folder / name):
                return folder / name
    return name
