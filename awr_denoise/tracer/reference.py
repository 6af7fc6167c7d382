"""High-spp reference renders, cached as half-float EXRs under ``data/references``.

``python -m awr_denoise.tracer.reference SCENE [--spp N] [--seed S] [--force]`` renders a
scene's reference with the Sobol' sampler and writes ``data/references/<scene>.exr``; its
``awr:*`` header (:mod:`awr_denoise.io.provenance`) records the scene, spp, sampler and seed.
:func:`load_reference` returns a cached reference or renders it when missing. Reading and
writing go through :mod:`awr_denoise.io` (extra ``exr``).
"""

from __future__ import annotations

import argparse
import contextlib
import os
from pathlib import Path

import numpy as np
from .._progress import tqdm

from .._places import cache_folder, checkout_data
from ..buffers import SampleBuffer
from ..io import provenance, read_header, read_image, read_provenance, write_image
from ..io.atomic import STAGING_NAME, check_writable
from ..requests import SampleRequest
from .integrator import PathTracer
from .scene import load_scene
from .scenes import BUNDLED_SCENES

__all__ = ["DEFAULT_REFERENCE_SPP", "REFERENCE_SEED", "reference_dir", "reference_path", "render_reference",
           "stored_reference", "load_reference", "read_reference_header", "main"]

DEFAULT_REFERENCE_SPP = 1024
"""Samples per pixel of a reference when none is asked for."""

REFERENCE_SEED = 7919
"""Seed of references: different from the default render seed 0, so a render at seed 0 and
its reference are independent estimates."""

_PASS_SPP = 32  # samples per pixel traced per pass (bounds memory; passes are merged exactly)
_HALF_MAX = 65504.0


def reference_dir() -> Path:
    """Where references are cached.

    ``$AWR_DENOISE_REFERENCE_DIR`` if set (a folder, or a path to create one at; a file or an empty value is a
    ``ValueError``); else the repository's ``data/references`` when running from a checkout;
    else ``references`` in the user's cache folder (``$XDG_CACHE_HOME/awr-denoise``, by default
    ``~/.cache/awr-denoise``).
    """
    override = os.environ.get("AWR_DENOISE_REFERENCE_DIR")
    if override is not None and not override.strip():
        # Read as unset, it sent a job's missing references into the checkout's tracked data/references (an
        # attack pass), where an empty value of every other variable is refused.
        raise ValueError("AWR_DENOISE_REFERENCE_DIR: empty; unset it for the default folder")
    if override:
        if os.path.exists(override) and not os.path.isdir(override):  # found now, not after a render
            raise ValueError(f"AWR_DENOISE_REFERENCE_DIR: {override} is not a folder")
        return Path(override)
    repo_data = checkout_data()
    return (repo_data if repo_data is not None else cache_folder()) / "references"


def _check_scene_name(scene_name: str) -> None:
    if scene_name not in BUNDLED_SCENES:
        raise ValueError(f"scene_name: {scene_name!r} is not one of {', '.join(BUNDLED_SCENES)}")


def reference_path(scene_name: str) -> Path:
    """Path of the cached reference EXR of a bundled scene."""
    _check_scene_name(scene_name)
    return reference_dir() / f"{scene_name}.exr"


def render_reference(scene_name: str, *, spp: int = DEFAULT_REFERENCE_SPP, seed: int = REFERENCE_SEED,
                     sampler: str = "sobol", path: str | Path | None = None, progress: bool = False,
                     threads: int = 2, workers: str = "threads") -> np.ndarray:
    """Render a bundled scene at ``spp`` and write it as a half-float EXR; returns (H, W, 3) float64.

    The image is rendered in passes of 32 spp whose statistics are merged exactly; the EXR
    header records scene, spp, sampler and seed (``awr:scene``, ``awr:spp``, ...). ``threads``
    and ``workers`` are passed to :class:`PathTracer` (the image does not depend on them).
    """
    _check_scene_name(scene_name)
    if int(spp) < 1:
        raise ValueError(f"spp: {spp} must be >= 1")
    target = Path(path) if path is not None else reference_path(scene_name)
    # A FIFO or a folder where the reference goes: refused now, not after minutes of rendering. The folders
    # made for it are removed again if the reference is not written (an interrupted or refused run left them).
    missing = [folder for folder in [target.parent, *target.parent.parents] if not os.path.lexists(folder)]
    for folder in missing:
        if STAGING_NAME.match(folder.name):
            raise ValueError(f"{target}: its folder {folder.name} would be named as awr's staging folders, which "
                             "later writes remove as leftovers; write elsewhere")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # a dangling link, a file on the way, a read-only or virtual file system
        named = os.environ.get("AWR_DENOISE_REFERENCE_DIR") if path is None else None
        if not named:
            if path is None:  # the default folder: say which setting moves it (a read-only home)
                raise OSError(exc.errno, f"{exc.strerror or exc} (the references' folder: set "
                                         "AWR_DENOISE_REFERENCE_DIR to one that can be written)",
                              str(target.parent)) from None
            raise
        # A setting's error is the user's: named, and read by the command line as bad input (exit 2).
        why = (f"a link to {os.readlink(target.parent)}, which does not exist" if target.parent.is_symlink()
               else exc.strerror or str(exc))
        raise ValueError(f"AWR_DENOISE_REFERENCE_DIR: cannot make the folder {target.parent} ({why})") from None
    try:
        return _render_into(target, scene_name, spp, seed, sampler, progress, threads, workers)
    except BaseException:
        for folder in missing:  # the deepest first: each empty now, unless someone else wrote there meanwhile
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise


def _render_into(target: Path, scene_name: str, spp: int, seed: int, sampler: str, progress: bool, threads: int,
                 workers: str) -> np.ndarray:
    """:func:`render_reference`'s render and write, its folder made."""
    check_writable(target, overwrite=True)
    scene = load_scene(scene_name)
    tracer = PathTracer(scene, seed=seed, sampler=sampler, threads=threads, workers=workers)
    buffer = SampleBuffer.empty(tracer.shape)
    passes = range(0, int(spp), _PASS_SPP)
    if progress:
        passes = tqdm(passes, desc=f"reference {scene_name}", unit="pass")
    try:
        for first in passes:
            count = min(_PASS_SPP, int(spp) - first)
            buffer = buffer.merge(tracer(SampleRequest.uniform(tracer.shape, count, first_index=first)))
    finally:
        tracer.close()
    stored = stored_reference(buffer.mean)
    header = provenance(scene=scene_name, spp=int(spp), sampler=sampler, seed=int(seed),
                        nonfinite=int(buffer.nonfinite), render_seconds=round(float(tracer.stats["seconds"]), 1))
    write_image(target, stored, header=header, half=stored.dtype == np.float16, overwrite=True)
    return stored.astype(np.float64)


def stored_reference(image: np.ndarray) -> np.ndarray:
    """A reference as its file holds it: half floats where every pixel fits below the half maximum (the bundled
    references), else float32. A clip to the half maximum would store a value the readers refuse as a clamp.

    >>> import numpy as np
    >>> stored_reference(np.array([[[1.0, 300.0, 0.0]]])).dtype, stored_reference(np.array([[[7e4, 1.0, 0.0]]])).dtype
    (dtype('float16'), dtype('float32'))
    """
    image = np.maximum(image, 0.0)  # means of radiance: a negative is rounding
    with np.errstate(over="ignore"):  # past the half range: Inf, and float32 then
        half = image.astype(np.float16)
    return half if (np.abs(half) < _HALF_MAX).all() else image.astype(np.float32)


def read_reference_header(path: str | Path) -> dict[str, str]:
    """How a reference EXR was made: its ``awr:`` attributes without the prefix, as strings.

    References written before the provenance builder used ``awr_*`` keys; they read the same.
    """
    return {k: str(v) for k, v in read_provenance(read_header(path)).items()}


def _check_cached(path: Path, scene_name: str, made: dict[str, str]) -> None:
    """Refuse a cached reference whose header says it is something else: another scene's reference, or a sample
    dump or request map (their R, G, B read as an image). Either was used, exit 0, every error against it wrong
    (an attack pass); only the size was checked."""
    if "semantics" in made:
        raise ValueError(f"{path}: is a {made['semantics']} file (awr:semantics), not the reference image of "
                         f"{scene_name}: remove it to render it again")
    if made.get("scene", scene_name) != scene_name:
        raise ValueError(f"{path}: holds the reference of scene {made['scene']!r} (awr:scene), not of {scene_name!r}: "
                         "remove it to render it again")


def load_reference(scene_name: str, *, spp: int | None = None) -> np.ndarray:
    """The high-spp reference image of a bundled scene, (H, W, 3) float64.

    Reads ``reference_path(scene_name)``; renders and caches it first when it is missing, or
    when ``spp`` is given and differs from the cached file's spp.
    """
    path = reference_path(scene_name)
    if path.is_file():
        made = read_reference_header(path)
        _check_cached(path, scene_name, made)
        if spp is None or made.get("spp") == str(int(spp)):
            return read_image(path, channels=("R", "G", "B")).astype(np.float64)
    return render_reference(scene_name, spp=DEFAULT_REFERENCE_SPP if spp is None else int(spp))


def main(argv: list[str] | None = None) -> int:
    """Command line: ``python -m awr_denoise.tracer.reference SCENE [SCENE ...] [--spp N]``."""
    parser = argparse.ArgumentParser(prog="python -m awr_denoise.tracer.reference",
                                     description="Render and cache high-spp reference images of bundled scenes.")
    parser.add_argument("scenes", nargs="+", metavar="SCENE", help=f"one of {', '.join(BUNDLED_SCENES)}, or 'all'")
    parser.add_argument("--spp", type=int, default=DEFAULT_REFERENCE_SPP, help="samples per pixel")
    parser.add_argument("--seed", type=int, default=REFERENCE_SEED)
    parser.add_argument("--sampler", default="sobol", choices=("independent", "sobol"))
    parser.add_argument("--threads", type=int, default=2, help="number of workers")
    parser.add_argument("--workers", default="processes", choices=("threads", "processes"),
                        help="worker kind (processes scale past the GIL; the image is the same)")
    parser.add_argument("--force", action="store_true", help="re-render even if a cached file has this spp")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    names = list(BUNDLED_SCENES) if args.scenes == ["all"] else args.scenes
    for name in names:
        if name not in BUNDLED_SCENES:
            parser.error(f"SCENE: {name!r} is not one of {', '.join(BUNDLED_SCENES)}, all")
    for name in names:
        path = reference_path(name)
        if path.is_file() and not args.force and read_reference_header(path).get("spp") == str(args.spp):
            print(f"{name}: cached at {path} ({args.spp} spp)")
            continue
        image = render_reference(name, spp=args.spp, seed=args.seed, sampler=args.sampler, threads=args.threads,
                                 workers=args.workers, progress=not args.quiet)
        print(f"{name}: wrote {path} ({image.shape[1]}x{image.shape[0]}, {args.spp} spp, "
              f"mean {image.mean(axis=(0, 1)).round(4).tolist()})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
