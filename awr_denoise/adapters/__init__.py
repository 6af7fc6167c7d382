"""Adapters that plug existing renderers into the ask/tell loop.

Each adapter is a :class:`~awr_denoise.requests.Renderer`: it renders exactly the samples of a
:class:`~awr_denoise.requests.SampleRequest` and returns their statistics. Adapters depend on
optional extras and import them lazily, so importing this package costs nothing:

- :mod:`awr_denoise.adapters.mitsuba`: Mitsuba 3 (extra ``mitsuba``), with bundled benchmark
  scenes in :mod:`awr_denoise.adapters.mitsuba_scenes`.
"""

from __future__ import annotations

__all__: list[str] = []
