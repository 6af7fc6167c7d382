"""What a benchmark's results file records: JSON-ready values, the machine, its load, the command.

Shared by ``awr bench`` and the scripts in ``benchmarks/``, which write their results to
``benchmarks/results/*.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import numpy as np

from .._checks import file_option
from ..io.atomic import atomic_write

__all__ = ["json_ready", "write_json", "update_section", "results_file", "machine_info", "load_average",
           "command_line"]


def json_ready(value: Any) -> Any:
    """``value`` with numpy scalars made Python ones and non-finite floats made strings.

    JSON has no NaN or infinity; ``"inf"``, ``"-inf"`` and ``"nan"`` read back with
    ``float()``. Dict keys become strings, tuples lists.

    Examples
    --------
    >>> json_ready({"a": (np.float64(0.5), np.int64(3)), 1: float("inf"), "ok": np.bool_(True)})
    {'a': [0.5, 3], '1': 'inf', 'ok': True}
    """
    if isinstance(value, dict):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if np.isfinite(v) else str(v)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def write_json(path: str | os.PathLike[str], data: Any, *, indent: int = 1) -> Path:
    """Write :func:`json_ready` ``data`` to ``path`` (parents created), ending with a newline.

    Written whole or not at all (:func:`awr_denoise.io.atomic.atomic_write`): a run killed while it
    wrote its results left an empty file, every section of it lost.

    Parameters
    ----------
    path
        The results file.
    data
        What to write.
    indent
        JSON indentation.

    Returns
    -------
    pathlib.Path
        ``path``.

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     out = write_json(Path(tmp) / "results" / "x.json", {"spp": np.int64(4)})
    ...     out.read_text()
    '{\\n "spp": 4\\n}\\n'
    """
    path = Path(path)
    text = json.dumps(json_ready(data), indent=indent) + "\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda temporary: Path(temporary).write_text(text, encoding="utf-8"), overwrite=True)
    return path


def update_section(path: str | os.PathLike[str], section: str, rows: Any, command: str,
                   *packages: str) -> Path:
    """Replace one section of a results file (its rows, the command that made them, the machine),
    keeping its other sections: a script run for one section, or into a trial file, leaves the rest.
    No rows is refused (``ValueError``): a run that measured nothing keeps the stored section.

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     out = write_json(Path(tmp) / "r.json", {"old": {"rows": [1]}})
    ...     _ = update_section(out, "new", [2], "bench.py new")
    ...     data = json.loads(out.read_text())
    >>> data["old"], data["new"]["rows"], data["new"]["command"]
    ({'rows': [1]}, [2], 'bench.py new')
    """
    path = Path(path)
    if rows is None or (hasattr(rows, "__len__") and len(rows) == 0):
        raise ValueError(f"{section}: nothing was measured; {path} keeps its section")
    text = path.read_text(encoding="utf-8") if path.exists() else ""
    data = json.loads(text) if text.strip() else {}  # an empty file (``mktemp``'s) is a new one
    data[section] = {"command": command, "machine": machine_info(*packages), "rows": rows}
    return write_json(path, data)


def results_file(value: str) -> Path:
    """An ``--output`` option's results file, checked before the run (an ``argparse`` type).

    A folder, a file that is not a results file (a JSON object) or a folder that is a file was found
    only when the run wrote its results, its work lost. Here each is refused up front, as
    ``argparse`` refuses a bad value: one line, exit 2.

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     fresh = results_file(str(Path(tmp) / "new" / "r.json"))
    ...     _ = (Path(tmp) / "list.json").write_text("[]")
    ...     try:
    ...         results_file(str(Path(tmp) / "list.json"))
    ...     except argparse.ArgumentTypeError as error:
    ...         refused = str(error)
    >>> fresh.name, refused.endswith("not a results file (a JSON object)")
    ('r.json', True)
    """
    path = file_option(value)  # not empty, not a name ending in a folder's / (which Path drops)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{value!r}: a folder, not a results file")
    folder = next((p for p in path.absolute().parents if p.exists()), None)
    if folder is not None and not folder.is_dir():
        raise argparse.ArgumentTypeError(f"{value}: {folder} is not a folder")
    if path.exists():
        try:
            text = path.read_text(encoding="utf-8")
            data = json.loads(text) if text.strip() else {}  # an empty file (``mktemp``'s) is a new one
        except (OSError, UnicodeDecodeError, ValueError) as error:
            raise argparse.ArgumentTypeError(f"{value}: cannot be read as a results file ({error})") from None
        if not isinstance(data, dict):
            raise argparse.ArgumentTypeError(f"{value}: not a results file (a JSON object)")
    return path


def machine_info(*packages: str) -> dict[str, Any]:
    """The machine and software a measurement ran on.

    Parameters
    ----------
    *packages
        Distributions whose installed version to add (``"missing"`` when not installed).

    Returns
    -------
    dict
        ``python``, ``platform``, ``processor``, ``machine``, ``cpus``, ``numpy`` and one entry
        per package.

    Examples
    --------
    >>> info = machine_info("scipy")
    >>> sorted(info)
    ['cpus', 'machine', 'numpy', 'platform', 'processor', 'python', 'scipy']
    """
    info: dict[str, Any] = {"python": sys.version.split()[0], "platform": platform.platform(),
                            "processor": platform.processor() or platform.machine(),
                            "machine": platform.machine(), "cpus": os.cpu_count(), "numpy": np.__version__}
    for name in packages:
        try:
            info[name] = version(name)
        except PackageNotFoundError:
            info[name] = "missing"
    return info


def load_average() -> list[float] | None:
    """The 1, 5 and 15 minute load averages (``None`` where the system has none).

    Other processes on the machine skew every timing; results record the load at the start
    and the end of a run.

    Examples
    --------
    >>> load = load_average()
    >>> load is None or len(load) == 3
    True
    """
    try:
        return list(os.getloadavg())
    except (AttributeError, OSError):  # not available on Windows
        return None


def command_line(script: str, argv: Sequence[str] | None = None) -> str:
    """The command that reproduces a run: ``python <script> <arguments>``.

    Parameters
    ----------
    script
        The script as run from the repository root, e.g. ``benchmarks/bench_core.py``.
    argv
        Its arguments; ``None`` takes them from :data:`sys.argv`.

    Examples
    --------
    >>> command_line("benchmarks/bench_core.py", ["--only", "levels"])
    'python benchmarks/bench_core.py --only levels'
    """
    args = sys.argv[1:] if argv is None else list(argv)
    return " ".join(["python", script, *args])
