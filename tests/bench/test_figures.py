"""The benchmark's figures (awr_denoise.bench.figures)."""

from __future__ import annotations

import numpy as np
import pytest

from awr_denoise.bench.figures import error_window


def test_error_window_finds_the_worst_region():
    err = np.zeros((40, 50))
    err[30:36, 41:47] = 1.0  # near a corner: the window must stay inside the image
    rows, cols = error_window(err, 10)
    assert rows.stop - rows.start == 10 and cols.stop - cols.start == 10
    assert rows.start <= 30 and rows.stop >= 36 and cols.start <= 41 and cols.stop >= 47
    assert rows.stop <= 40 and cols.stop <= 50
    rows, cols = error_window(err, 100)  # clipped to the image's shorter side
    assert (rows.start, rows.stop) == (0, 40) and cols.stop - cols.start == 40
    assert cols.start <= 41 and 47 <= cols.stop <= 50


@pytest.mark.tracer
def test_every_figure_is_written(tiny_run):
    _, out = tiny_run
    for name in ("bench_error_vs_spp.png", "bench_error_vs_time.png", "bench_density.png", "bench_crops.png",
                 "bench_cs_relmse.png", "bench_cs_bias_variance.png", "bench_domain_crops.png"):
        assert (out / "docs" / "img" / name).stat().st_size > 1000
