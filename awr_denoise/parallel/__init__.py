"""Parallel and distributed execution: frame sequences, tiled reconstruction, tiled rendering.

Everything here takes any :class:`concurrent.futures.Executor` through ``executor=``. Without one,
work runs on in-process threads (:class:`~concurrent.futures.ThreadPoolExecutor`), which need
neither a cluster nor Dask: numpy, PyWavelets and embreex release the GIL in their array operations;
on two cores, over frames, two threads were about as much faster than one as two Dask worker
processes (docs/distributed.md has the measurements). :func:`get_executor` makes the other kinds on
demand:

* ``"threads"``: a thread pool (the default);
* ``"processes"``: a process pool on this machine;
* ``"dask"``: with ``pip install "awr-denoise[dask]"``, a :class:`distributed.LocalCluster` of
  worker processes, or a connection to a running scheduler (``scheduler="tcp://host:8786"``
  or a scheduler file), which is how one spreads work over several machines.

Three kinds of work are offered, each split into independent tasks:

* :func:`denoise_frames`: one task per frame of a sequence. Tasks get file *paths*, read
  their sample dump, reconstruct and write the image themselves (:func:`denoise_frame`), so
  no pixel crosses the network; the result is bitwise identical to a serial run.
* :func:`reconstruct_tiled`: one task per tile of a large frame. Each task gets only its tile
  plus a halo wide enough for the wavelet support at every level (:func:`halo_width`), and the
  thresholding domain's scale is fixed globally, so the result matches the whole-frame
  reconstruction to rounding (docs/distributed.md derives the halo and the tolerance).
* :func:`render_tiled` / :class:`TiledRenderer`: every round of an adaptive render is split
  into pixel tiles rendered on the workers. The renderer is built *in the worker* from a
  picklable factory (:class:`RendererSpec`), tile statistics are assembled exactly, and with
  addressable random numbers the result equals the serial render bit for bit.

The package is split by concept: :mod:`~awr_denoise.parallel.executors`,
:mod:`~awr_denoise.parallel.frames`, :mod:`~awr_denoise.parallel.tiles` and
:mod:`~awr_denoise.parallel.render`. The command line's ``--workers``, ``--scheduler`` and
``--executor`` options live with the command line (``awr_denoise.cli.parallel_options``).
"""

from __future__ import annotations

from .executors import DASK_INSTALL_HINT, EXECUTOR_KINDS, get_executor
from .frames import FrameResult, FramesFailedError, denoise_frame, denoise_frames
from .render import RendererSpec, TiledRenderer, render_tiled
from .tiles import halo_width, reconstruct_tiled, tile_grid

__all__ = [
    "DASK_INSTALL_HINT",
    "EXECUTOR_KINDS",
    "FrameResult",
    "FramesFailedError",
    "RendererSpec",
    "TiledRenderer",
    "denoise_frame",
    "denoise_frames",
    "get_executor",
    "halo_width",
    "reconstruct_tiled",
    "render_tiled",
    "tile_grid",
]
