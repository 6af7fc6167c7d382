"""Helpers of the command-line robustness tests: a folder with a dump, a reference, a request
and a frame sequence, and the checks every refusal must pass."""

from __future__ import annotations

import hashlib
import os
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from awr_denoise import SampleBuffer, SampleRequest
from awr_denoise.bench.measure import awr_command
from awr_denoise.io import write_image, write_request, write_sample_buffer

H, W = 24, 32


def dump_buffer(seed: int = 0, shape: tuple[int, int] = (H, W)) -> SampleBuffer:
    rng = np.random.default_rng(seed)
    mean = np.abs(0.5 + 0.1 * rng.standard_normal(shape + (3,)))
    return SampleBuffer.from_moments(np.full(shape, 8), mean, np.full(shape + (3,), 0.04))


@dataclass
class Work:
    """A folder holding ``d.exr`` (dump), ``b.exr`` (another batch), ``ref.exr`` (image),
    ``req.exr`` (request) and ``shot.0001-0003.exr`` (frames)."""

    root: Path

    def __truediv__(self, name: str) -> Path:
        return self.root / name

    def state(self) -> dict[str, str]:
        """Every entry below the folder (hidden ones too) with its type and content hash."""
        out = {}
        for dirpath, dirnames, filenames in os.walk(self.root):
            for name in dirnames + filenames:
                p = Path(dirpath) / name
                rel = str(p.relative_to(self.root))
                if p.is_symlink():
                    out[rel] = "link:" + os.readlink(p)
                elif p.is_dir():
                    out[rel] = "dir"
                elif p.is_file():
                    out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
                else:
                    out[rel] = "special"
        return out

    def temporaries(self) -> list[str]:
        return [k for k in self.state() if Path(k).name.startswith(".awr-") or ".tmp" in Path(k).name]


def make_work(tmp_path: Path) -> Work:
    w = Work(tmp_path)
    write_sample_buffer(w / "d.exr", dump_buffer(0))
    write_sample_buffer(w / "b.exr", dump_buffer(1))
    write_image(w / "ref.exr", dump_buffer(2).mean)
    write_request(w / "req.exr", SampleRequest.uniform((H, W), 8, first_index=8, round=1))
    for i in (1, 2, 3):
        write_sample_buffer(w / f"shot.{i:04d}.exr", dump_buffer(10 + i))
    return w


def with_attribute(path: Path, key: str, value: object) -> Path:
    """``path`` written again with one header attribute set to ``value``, as another tool could write it: the
    library's writers refuse to give their own attributes (``awr:nonfinite``, ``awr:round``) values the data do not
    have, so a file that does is made here."""
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        header = dict(f.header())
        channels = {name: channel.pixels for name, channel in f.channels().items()}
    header[key] = value
    OpenEXR.File(header, channels).write(str(path))
    return path


def one_error_line(err: str, *needles: str) -> str:
    """The single ``awr: error:`` line of a refusal, holding every needle; no traceback."""
    lines = [line for line in err.splitlines() if line.strip() and "it/s]" not in line]
    assert len(lines) == 1, err
    assert lines[0].startswith("awr: error: "), err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def run_awr(args: Sequence[object], cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([*awr_command(), *map(str, args)], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout)
