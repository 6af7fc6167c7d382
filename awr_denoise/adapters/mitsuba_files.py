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
- every attribute value of every element may name a file, read every way Mitsuba's
  substitution may leave it: ``$name`` replaced by each value a ``<default>`` of the scene or of
  an include gives it (which one Mitsuba keeps depends on which include it reads first) or by the
  render's parameter, the longest name first, ``\\$`` a literal ``$``;
- it is looked up in every folder any of Mitsuba's lookups may use: the working folder, the
  scene's folder, each XML file's folder (and its target's, for a symbolic link) and each
  ``<path>`` folder. Every file found there that is not a folder is listed (a name found
  nowhere is not: Mitsuba cannot read it, so no output can replace it and it cannot block);
- included files found so are read in turn, until no include names a file not yet read (regular
  files only: a FIFO is listed, never opened); a scene of more than 1000 XML files, or a value
  that may read in more than 256 ways, is refused rather than half checked;
- the files plugins look up by a fixed name through the same resolver are listed from each of
  those folders too: plugin libraries (``plugins/*.so``), conductor data (``data/ior/*.spd``),
  the sun and sky model's tables (``data/sunsky/*.bin``) and ``data/srgb.coeff``.

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

from .mitsuba_scenes import ALL_SCENES

__all__ = ["scene_files"]

# In one left-to-right pass, as pugixml reads: markup it skips (comments, CDATA, processing
# instructions such as the XML declaration, the DOCTYPE with its internal subset, never expanded),
# or an element's start tag, whose quoted values may hold "<!--" or ">".
_MARKUP = re.compile(r"""<!--.*?-->|<!\[CDATA\[.*?\]\]>|<\?.*?\?>|<!DOCTYPE(?:[^\[>]|\[.*?\])*>"""
                     r"""|<([^\s/>!?]+)([^"'>]*(?:(?:"[^"]*"|'[^']*')[^"'>]*)*)>""", re.DOTALL)  # linear: unrolled
_ATTRIBUTE = re.compile(r"""([^\s=/>"']+)\s*=\s*(?:"([^"]*)"|'([^']*)')""")
_REFERENCE = re.compile(r"&(?:(amp|lt|gt|quot|apos)|#([0-9]+)|#x([0-9a-fA-F]+));")
_LATIN1 = re.compile(rb"""<\?xml[^>]*encoding\s*=\s*["'](?:iso-8859-1|latin-?1)["']""", re.IGNORECASE)
_MAX_FILES = 1000  # included XML files read at most; a scene with more is refused, not half checked
_MAX_VARIANTS = 256  # the ways one value may read (its parameters' <default> values combined); more: refused
_RANK = {"include": 0, "filename": 1}


class _Walk:
    """What one walk over a scene gathers: every value each parameter may take (``$name``), the
    values its elements hold, and the folders a name may be looked up in."""

    def __init__(self, scene: Path, params: Mapping[str, Any]) -> None:
        self.scene = scene
        # The render's parameters are the only values of theirs; a <default> cannot change them.
        self.fixed = {"$" + str(name) for name in params}
        self.params: dict[str, list[str]] = {"$" + str(name): [str(value)] for name, value in params.items()}
        self.values: dict[str, str] = {}  # raw value -> how the message names it
        self.paths: list[tuple[str, Path]] = []  # <path value=...> and the folder of its file
        self.includes: list[tuple[str, Path]] = []  # <include filename=...> and the folder of its file
        self.folders: list[Path] = [Path()]
        self.read: set[Path] = set()

    def define(self, name: str, value: str) -> None:
        """One more value ``$name`` may take: each ``<default>`` met (Mitsuba keeps the first it
        reads, and which file it reads first is what a superset does not decide)."""
        key = "$" + name
        if key not in self.fixed and value not in self.params.setdefault(key, []):
            self.params[key].append(value)

    def substituted(self, value: str) -> list[str]:
        """Every way ``value`` may read once Mitsuba's ``substitute_parameters`` has replaced its
        parameters (the longest name first, ``\\$`` a literal ``$``; a ``<default>`` whose value
        holds another parameter substituted in turn, along a chain of any length); none left with
        an undefined one (Mitsuba refuses the scene there). More than ``_MAX_VARIANTS`` readings
        are refused, not cut short: a reading left out would be a file left unchecked."""
        keys = sorted(self.params, key=len, reverse=True)
        found: list[str] = []
        pending, seen = [value], {value}
        for _ in range(len(keys) + 1):  # each round resolves one more link of the longest chain
            for key in keys:
                done = []
                for text in pending:
                    positions = _unescaped_positions(text, key)
                    if not positions:
                        done.append(text)
                        continue
                    for replacement in self.params[key]:
                        out, last = [], 0
                        for pos in positions:
                            out.append(text[last:pos] + replacement)
                            last = pos + len(key)
                        done.append("".join(out) + text[last:])
                pending = list(dict.fromkeys(done))
                if len(pending) + len(found) > _MAX_VARIANTS:
                    raise ValueError(f"{self.scene}: {value!r} may read in more than {_MAX_VARIANTS} ways through "
                                     "its parameters' <default> values; the files it names are not checked")
            found += [text for text in pending if not _unescaped_positions(text, "$")]
            pending = [text for text in pending if _unescaped_positions(text, "$") and text not in seen]
            seen.update(pending)
            if not pending:
                break
        return [text.replace("\\$", "$") for text in dict.fromkeys(found)]

    def folder(self, folder: Path) -> None:
        if folder not in self.folders:
            self.folders.append(folder)


def _unescaped_positions(text: str, key: str) -> list[int]:
    """Where ``key`` stands in ``text`` not after a backslash, as Mitsuba's search finds them."""
    positions, pos = [], text.find(key)
    while pos >= 0:
        if not (pos > 0 and text[pos - 1] == "\\"):
            positions.append(pos)
        pos = text.find(key, pos + len(key))
    return positions


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
    if isinstance(scene, str) and scene in ALL_SCENES and not os.path.lexists(first):
        return []  # a bundled scene, built from a dict
    walk = _Walk(first, params or {})
    pending, done, state = [first], 0, None
    while pending:  # until no include names a file not yet read: a later <default> or <path> may
        for file in pending:
            _read_file(walk, file)
        for raw, base in walk.paths:
            for value in walk.substituted(raw):
                for folder in _candidates(value, [base, *walk.folders]):
                    if folder.is_dir():
                        walk.folder(folder)
        # Every include again when a parameter or a folder is new, else only the new ones.
        now = (sum(map(len, walk.params.values())), len(walk.folders))
        start, done, state = (0 if now != state else done), len(walk.includes), now
        pending = list(dict.fromkeys(file for raw, base in walk.includes[start:] for value in walk.substituted(raw)
                                     for file in _candidates(value, [base, *walk.folders])
                                     if file.is_file() and file.resolve() not in walk.read))  # a FIFO: never opened
        if len(walk.read) + len(pending) > _MAX_FILES:
            raise ValueError(f"{first}: includes more than {_MAX_FILES} XML files; the files they name are not "
                             "checked")
    named: dict[str, str] = {}
    for raw, what in walk.values.items():
        for value in walk.substituted(raw):
            if _RANK.get(what, 2) < _RANK.get(named.get(value, ""), 3):  # the message names its likeliest use
                named[value] = what
    files: list[tuple[str, Path]] = []
    seen: set[Path] = set()
    listings: dict[Path, set[str]] = {}
    for value, what in named.items():
        for path in _found(value, walk.folders, listings):
            if path not in seen:
                seen.add(path)
                files.append((f"{what} {value}", path))
    for name, path in _resources(walk.folders):
        if path not in seen:
            seen.add(path)
            files.append((f"resource {name}", path))
    return files


# Files Mitsuba's plugins look up by a fixed name through the same resolver, so a copy beside the
# scene wins: each plugin's library (plugins/<type>.so, loaded on first use, any plugin the scene
# uses implicitly too), a conductor's data/ior/<material>.eta.spd and .k.spd, the sun and sky
# model's data/sunsky/*.bin, the spectral variants' data/srgb.coeff (core/plugin.cpp,
# render/ior.h, render/sunsky.h, render/srgb.cpp).
_RESOURCE_FOLDERS = (("plugins", (".so", ".dll", ".dylib")), ("data/ior", (".spd",)), ("data/sunsky", (".bin",)))
_RESOURCE_FILES = ("data/srgb.coeff",)


def _resources(folders: list[Path]) -> list[tuple[str, Path]]:
    """``(name, path)`` of every such file present in ``folders`` (not a folder itself)."""
    found = []
    for folder in folders:
        for sub, suffixes in _RESOURCE_FOLDERS:
            try:
                names = sorted(os.listdir(folder / sub))
            except (OSError, ValueError):  # no such folder: nothing looked up there
                continue
            found += [(f"{sub}/{name}", folder / sub / name) for name in names if name.endswith(suffixes)]
        found += [(name, folder / name) for name in _RESOURCE_FILES]
    # As Mitsuba's lookup: a broken link is no file (it looks further), a FIFO is one (refused).
    return [(name, path) for name, path in found if os.path.exists(path) and not os.path.isdir(path)]


def _read_file(walk: _Walk, path: Path) -> None:
    """Gather one XML file's values, ``<default>`` values, ``<path>`` folders and includes."""
    key = path.resolve()
    if key in walk.read or not path.is_file():
        return
    walk.read.add(key)
    walk.folder(path.parent)
    walk.folder(key.parent)  # where a loader that resolves links looks
    try:
        text = _decoded(path.read_bytes())
    except OSError as exc:
        raise ValueError(f"{path}: not a readable Mitsuba XML scene ({exc.strerror})") from None
    for tag in _MARKUP.finditer(text):
        name = tag.group(1)
        if name is None:
            continue  # a comment, CDATA, a processing instruction or the DOCTYPE: pugixml skips them
        attributes: dict[str, str] = {}
        for attribute in _ATTRIBUTE.finditer(tag.group(2)):
            value = attribute.group(2) if attribute.group(2) is not None else attribute.group(3)
            attributes.setdefault(attribute.group(1), _unescaped(value))  # pugixml reads the first
        for key, value in attributes.items():
            what = "include" if name == "include" else "filename" if _names_a_file(name, key, attributes) else key
            if _RANK.get(what, 2) < _RANK.get(walk.values.get(value, ""), 3):
                walk.values[value] = what
        if name == "default" and "name" in attributes:
            walk.define(attributes["name"], attributes.get("value", ""))
        elif name == "path" and "value" in attributes:
            walk.paths.append((attributes["value"], path.parent))
        elif name == "include" and "filename" in attributes:
            walk.includes.append((attributes["filename"], path.parent))


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
    if "&" not in value and "\n" not in value and "\r" not in value and "\t" not in value:
        return value  # the common case, as written
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


def _found(value: str, folders: list[Path], listings: dict[Path, set[str]]) -> list[Path]:
    """The candidates of ``value`` that exist and are not folders (a FIFO, a device or a link to
    one included: those are refused, never opened). A plain name is looked up in each folder's
    listing first (``listings``): a large scene's values are mostly numbers, and a stat of each in
    each folder took seconds."""
    if os.sep in value or (os.altsep and os.altsep in value) or value in (".", "..") or Path(value).is_absolute():
        candidates = _candidates(value, folders)
    else:
        candidates = [folder / value for folder in folders if value in _listing(folder, listings)]
    found = []
    for path in candidates:
        try:
            if os.path.exists(path) and not os.path.isdir(path):
                found.append(path)
        except (OSError, ValueError):  # a name too long, or holding a NUL: no such file
            continue
    return found


def _listing(folder: Path, listings: dict[Path, set[str]]) -> set[str]:
    if folder not in listings:
        try:
            listings[folder] = set(os.listdir(folder))
        except (OSError, ValueError):  # not a folder (any more), unreadable: nothing found there
            listings[folder] = set()
    return listings[folder]
