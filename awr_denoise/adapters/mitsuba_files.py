"""The files a Mitsuba 3 XML scene may read besides itself, found without loading it.

``awr render --renderer mitsuba SCENE.xml`` checks them with its other inputs before Mitsuba runs:
an output must never replace a texture, and a FIFO among them would block Mitsuba's loader in a
thread no signal reaches. Emulating exactly which file Mitsuba opens proved fragile (which
elements its parser visits, how its resolver's folders change inside includes, how pugixml
decodes a file), so the list is a superset, built from what Mitsuba's parser
(``src/core/parser.cpp``) and pugixml do:

- the text is decoded as pugixml decodes it (a byte-order mark, a Latin-1 declaration, else
  UTF-8, other declared encodings ignored); comments, CDATA, processing instructions and the
  DOCTYPE are skipped, and only the five XML entities and character references are replaced
  (``&t;`` stays ``&t;``, as in Mitsuba); malformed markup that pugixml tolerates is read too;
- every attribute value of every element, with ``$name`` replaced as Mitsuba does (the longest
  defined name first, ``\\$`` a literal ``$``; the ``<default>`` values of the scene and of its
  includes, the render's parameters first), may name a file;
- it is looked up in every folder any of Mitsuba's lookups may use: the working folder, the
  scene's folder, each XML file's folder (and its target's, for a symbolic link) and each
  ``<path>`` folder. Every file found there that is not a folder is listed (a name found
  nowhere is not: Mitsuba cannot read it, so no output can replace it and it cannot block);
- included files found so are read in turn (regular files only: a FIFO is listed, never opened).

The scene file may have any name: Mitsuba loads ``scene.txt`` as XML too.
"""

from __future__ import annotations

import codecs
import html
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .mitsuba_scenes import SCENE_NAMES

__all__ = ["scene_files"]

# Markup pugixml skips: comments, CDATA, processing instructions (the XML declaration), the DOCTYPE
# with its internal subset (never expanded).
_SKIPPED = re.compile(r"<!--.*?-->|<!\[CDATA\[.*?\]\]>|<\?.*?\?>|<!DOCTYPE(?:[^\[>]|\[.*?\])*>", re.DOTALL)
_TAG = re.compile(r"""<([^\s/>!?]+)((?:[^"'>]|"[^"]*"|'[^']*')*)>""")
_ATTRIBUTE = re.compile(r"""([^\s=/>"']+)\s*=\s*(?:"([^"]*)"|'([^']*)')""")
_REFERENCE = re.compile(r"&(?:(amp|lt|gt|quot|apos)|#([0-9]+)|#x([0-9a-fA-F]+));")
_LATIN1 = re.compile(rb"""<\?xml[^>]*encoding\s*=\s*["'](?:iso-8859-1|latin-?1)["']""", re.IGNORECASE)
_MAX_FILES = 1000  # included XML files read at most
_MAX_DEPTH = 32  # includes followed this deep (Mitsuba refuses a depth of 15)
_RANK = {"include": 0, "filename": 1}


class _Walk:
    """What one walk over a scene gathers: its parameters (``$name``, value; the longest name
    first), the values its elements hold, and the folders a name may be looked up in."""

    def __init__(self, params: Mapping[str, Any]) -> None:
        self.params: list[tuple[str, str]] = []
        for name, value in params.items():
            self.define(str(name), str(value))
        self.values: dict[str, str] = {}  # raw value -> how the message names it
        self.folders: list[Path] = [Path()]
        self.read: set[Path] = set()

    def define(self, name: str, value: str) -> None:
        """Define ``$name`` unless it is; equal lengths keep their order, as Mitsuba's insert."""
        key = "$" + name
        if any(known == key for known, _ in self.params):
            return
        at = next((i for i, (known, _) in enumerate(self.params) if len(key) > len(known)), len(self.params))
        self.params.insert(at, (key, value))

    def substituted(self, value: str) -> str | None:
        """``value`` as Mitsuba's ``substitute_parameters`` leaves it; None when a ``$`` is left
        over (an undefined parameter: Mitsuba refuses the scene if it gets there)."""
        for key, replacement in self.params:
            pos = value.find(key)
            while pos >= 0:
                if pos > 0 and value[pos - 1] == "\\":
                    pos = value.find(key, pos + len(key))
                else:
                    value = value[:pos] + replacement + value[pos + len(key):]
                    pos = value.find(key, pos + len(replacement))
        if any(value[i] == "$" and (i == 0 or value[i - 1] != "\\") for i in range(len(value))):
            return None
        return value.replace("\\$", "$")

    def folder(self, folder: Path) -> None:
        if folder not in self.folders:
            self.folders.append(folder)


def scene_files(scene: Any, params: Mapping[str, Any] | None = None) -> list[tuple[str, Path]]:
    """The files a Mitsuba XML scene may read besides itself, as ``(what, path)``.

    A superset (see the module's notes): every existing file, not a folder, that an attribute
    value of the scene or of its included files names in a folder Mitsuba may look in. A bundled
    scene name or a scene dict reads none.

    Parameters
    ----------
    scene
        The scene file (any name), a bundled scene name or a scene dict.
    params
        The render's parameters, as given to ``mi.load_file(scene, **params)``; they take
        precedence over the scene's ``<default>`` values.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> folder = Path(tempfile.mkdtemp())
    >>> for name in ("bunny_lod0.obj", "cube_lod0.obj", "glass.spd"):
    ...     _ = (folder / name).write_text("")
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
    walk = _Walk(params or {})
    _read_file(walk, first, 0)
    named: dict[str, str] = {}
    for raw, what in walk.values.items():
        value = walk.substituted(raw)
        if value and _RANK.get(what, 2) < _RANK.get(named.get(value, ""), 3):  # the message names its likeliest use
            named[value] = what
    files: list[tuple[str, Path]] = []
    seen: set[Path] = set()
    for value, what in named.items():
        for path in _found(value, walk.folders):
            if path not in seen:
                seen.add(path)
                files.append((f"{what} {value}", path))
    return files


def _read_file(walk: _Walk, path: Path, depth: int) -> None:
    """Gather one XML file's defaults, ``<path>`` folders and values, and follow its includes
    where they stand (document order: a default counts from there on)."""
    if depth > _MAX_DEPTH or len(walk.read) >= _MAX_FILES or not path.is_file():  # a FIFO: listed, never opened
        return
    key = path.resolve()
    if key in walk.read:
        return
    walk.read.add(key)
    walk.folder(path.parent)
    walk.folder(key.parent)  # where a loader that resolves links looks
    try:
        text = _decoded(path.read_bytes())
    except OSError as exc:
        raise ValueError(f"{path}: not a readable Mitsuba XML scene ({exc.strerror})") from None
    for tag in _TAG.finditer(_SKIPPED.sub(" ", text)):
        attributes: dict[str, str] = {}
        for attribute in _ATTRIBUTE.finditer(tag.group(2)):
            value = attribute.group(2) if attribute.group(2) is not None else attribute.group(3)
            attributes.setdefault(attribute.group(1), _unescaped(value))  # pugixml reads the first
        name = tag.group(1)
        for key, value in attributes.items():
            what = "include" if name == "include" else "filename" if _names_a_file(name, key, attributes) else key
            if _RANK.get(what, 2) < _RANK.get(walk.values.get(value, ""), 3):
                walk.values[value] = what
        if name == "default" and "name" in attributes:
            value = walk.substituted(attributes.get("value", ""))
            if value is not None:
                walk.define(attributes["name"], value)
        elif name == "path" and "value" in attributes:
            value = walk.substituted(attributes["value"])
            for folder in _candidates(value, [path.parent, *walk.folders]) if value else []:
                if folder.is_dir():
                    walk.folder(folder)
        elif name == "include" and "filename" in attributes:
            value = walk.substituted(attributes["filename"])
            for file in _candidates(value, [path.parent, *walk.folders]) if value else []:
                _read_file(walk, file, depth + 1)


def _names_a_file(tag: str, key: str, attributes: Mapping[str, str]) -> bool:
    return key == "filename" or (tag == "string" and key == "value" and attributes.get("name") == "filename")


def _decoded(data: bytes) -> str:
    """The text as pugixml reads it (``encoding_auto``): by its byte-order mark, Latin-1 when it
    declares it, else UTF-8; bytes that are not UTF-8 are kept as the surrogates Python gives
    undecodable file names, so they name the same files."""
    for bom, codec in ((codecs.BOM_UTF32_BE, "utf-32-be"), (codecs.BOM_UTF32_LE, "utf-32-le"),
                       (codecs.BOM_UTF8, "utf-8"), (codecs.BOM_UTF16_BE, "utf-16-be"),
                       (codecs.BOM_UTF16_LE, "utf-16-le")):
        if data.startswith(bom):
            return data[len(bom):].decode(codec, "replace")
    if data[:4] in (b"<\0?\0", b"<\0\0\0") or data[:2] == b"<\0":
        return data.decode("utf-16-le", "replace")
    if data[:2] == b"\0<":
        return data.decode("utf-16-be", "replace")
    if _LATIN1.match(data):
        return data.decode("latin-1")
    return data.decode("utf-8", "surrogateescape")


def _unescaped(value: str) -> str:
    """An attribute value as pugixml gives it: line ends and whitespace as spaces, the five XML
    entities and character references replaced, any other ``&name;`` kept as written."""
    value = value.replace("\r\n", "\n").replace("\r", "\n").replace("\n", " ").replace("\t", " ")
    return _REFERENCE.sub(_reference, value)


def _reference(match: re.Match[str]) -> str:
    if match.group(1):
        return html.unescape(f"&{match.group(1)};")
    code = int(match.group(2)) if match.group(2) else int(match.group(3), 16)
    return chr(code) if 0 < code <= 0x10FFFF else match.group(0)


def _candidates(value: str, folders: list[Path]) -> list[Path]:
    """``value`` in each of ``folders`` (itself if absolute)."""
    name = Path(value)
    return [name] if name.is_absolute() else [folder / name for folder in folders]


def _found(value: str, folders: list[Path]) -> list[Path]:
    """The candidates of ``value`` that exist and are not folders (a FIFO, a device or a link to
    one included: those are refused, never opened)."""
    found = []
    for path in _candidates(value, folders):
        try:
            if os.path.exists(path) and not os.path.isdir(path):
                found.append(path)
        except (OSError, ValueError):  # a name too long, or holding a NUL: no such file
            continue
    return found
