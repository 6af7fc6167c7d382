"""Where awr-denoise keeps the files it makes: a checkout's ``data`` folder, else the user's cache folder.

Run from a checkout (the source tree, or an editable install of it), the tracer's references, the bundled scene
files and the benchmarks' Mitsuba references live in the repository's ``data`` folder, the references tracked
there. An installed wheel has no such folder: the package's parent is ``site-packages``, whose ``data`` folder,
when another package ships one, is not ours. Taken for a checkout, an install wrote its references there (and
read another package's ``references/default.exr`` as the reference), and failed where ``site-packages`` is
read-only (an attack pass). A checkout is told by its ``pyproject.toml`` naming this project.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["checkout_data", "cache_folder", "shown_path"]

_PROJECT = 'name = "awr-denoise"'


def _checkout_root() -> Path | None:
    root = Path(__file__).resolve().parents[1]
    project = root / "pyproject.toml"
    try:
        named = project.is_file() and _PROJECT in project.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
    return root if named and (root / "awr_denoise").is_dir() else None


def checkout_data() -> Path | None:
    """The repository's ``data`` folder when this package runs from a checkout, else ``None`` (an install).

    Examples
    --------
    >>> from awr_denoise._places import checkout_data
    >>> checkout_data() is None or checkout_data().name == "data"
    True
    """
    root = _checkout_root()
    return None if root is None else root / "data"


def cache_folder() -> Path:
    """``$XDG_CACHE_HOME/awr-denoise``, or ``~/.cache/awr-denoise`` where that variable is unset, empty or relative
    (the XDG specification has relative values ignored); a ``ValueError`` naming the variable where there is no home.

    Examples
    --------
    >>> from awr_denoise._places import cache_folder
    >>> cache_folder().name
    'awr-denoise'
    """
    base = os.environ.get("XDG_CACHE_HOME", "")
    if os.path.isabs(base):
        return Path(base) / "awr-denoise"
    try:
        home = Path.home()
    except RuntimeError:  # a user without a home folder (a container's uid without a passwd entry)
        raise ValueError(f"XDG_CACHE_HOME: {'unset' if not base else 'relative'}, and there is no home folder to keep "
                         "awr-denoise's cache in; set it to an absolute folder (AWR_DENOISE_REFERENCE_DIR moves the "
                         "tracer's references alone)") from None
    return home / ".cache" / "awr-denoise"


def shown_path(path: str | os.PathLike[str]) -> str:
    """``path`` relative to the checkout when it lies inside one, by its name or through links (what a results file
    of the repository records: no machine's folder), else as given.

    Examples
    --------
    >>> from awr_denoise._places import checkout_data, shown_path
    >>> data = checkout_data()
    >>> data is None or shown_path(data / "references" / "default.exr") == "data/references/default.exr"
    True
    """
    root = _checkout_root()
    if root is not None:
        # By its name first (data/references may be a link elsewhere), where no ".." makes the name say another file.
        named = [] if ".." in Path(path).parts else [Path(os.path.abspath(path))]
        for form in (*named, Path(path).resolve()):
            if form.is_relative_to(root):
                return form.relative_to(root).as_posix()
    return str(path)
