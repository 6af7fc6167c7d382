"""``awr_denoise.bench.cache``: cached arrays written whole, read back only whole."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from awr_denoise.bench import cache


def test_arrays_and_one_array_come_back_as_written(tmp_path):
    arrays = {"count": np.arange(6).reshape(2, 3), "render": np.array('{"scene": "x"}')}
    back = cache.load_arrays(cache.save_arrays(tmp_path / "a" / "b.npz", arrays))
    assert set(back) == {"count", "render"} and np.array_equal(back["count"], arrays["count"])
    assert str(back["render"]) == '{"scene": "x"}'
    image = np.linspace(0, 1, 12).reshape(2, 2, 3)
    assert np.array_equal(cache.load_arrays(cache.save_arrays(tmp_path / "r.npy", image)), image)
    assert [p.name for p in sorted(tmp_path.rglob("*")) if p.is_file()] == ["b.npz", "r.npy"]  # no temporary left


def test_a_write_stopped_part_way_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    """Ctrl-C while a buffer's arrays were written left a file that opened with some of them (its features
    missing), which later runs measured without a word."""
    path = cache.save_arrays(tmp_path / "b.npz", {"mean": np.ones(3)})
    real = np.savez

    def stopped(f, **arrays):
        real(f, **{k: v for k, v in list(arrays.items())[:1]})  # part of it on disk, then the signal
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez", stopped)
    with pytest.raises(KeyboardInterrupt):
        cache.save_arrays(path, {"mean": np.zeros(3), "albedo_mean": np.zeros(3)})
    assert np.array_equal(cache.load_arrays(path)["mean"], np.ones(3))
    assert [p.name for p in tmp_path.iterdir()] == ["b.npz"]


def test_a_missing_file_is_none_without_a_word(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert cache.load_arrays(tmp_path / "none.npz") is None


@pytest.mark.parametrize("cut", [0, 10, 200])
def test_a_file_cut_short_is_none_with_a_warning_naming_it(tmp_path, cut):
    """A writer killed part way (by an older version, or another program) left a file numpy cannot read: every
    later run stopped with numpy's error, naming no file."""
    path = cache.save_arrays(tmp_path / "buffer.npz", {"mean": np.ones((32, 32, 3))})
    path.write_bytes(path.read_bytes()[:cut])
    with pytest.warns(UserWarning, match=r"buffer\.npz: unreadable .*; it is made again"):
        assert cache.load_arrays(path) is None


def test_a_file_its_check_refuses_is_none_with_the_reason(tmp_path):
    path = cache.save_arrays(tmp_path / "ref.npy", np.zeros((4, 4, 3)))
    with pytest.warns(UserWarning, match=r"ref\.npy: another size; it is made again"):
        assert cache.load_arrays(path, lambda a: "another size" if a.shape != (8, 8, 3) else None) is None
    assert cache.load_arrays(path, lambda a: None).shape == (4, 4, 3)


def test_a_file_of_the_other_kind_under_a_name_is_refused_not_a_crash(tmp_path):
    """An .npz under a reference's .npy name came back as a dict, and the reference's check asked for its shape."""
    path = tmp_path / "ref.npy"
    with open(path, "wb") as f:
        np.savez(f, mean=np.zeros((4, 4, 3)))
    with pytest.warns(UserWarning, match=r"ref\.npy: not what it should hold \(AttributeError"):
        assert cache.load_arrays(path, lambda a: None if a.shape == (4, 4, 3) else "shape") is None
