"""Streaming .npy files: what NpyWriter writes, np.load reads, and NpyRows reads back."""

from __future__ import annotations

import numpy as np
import pytest

from hybrid.npyio import NpyRows, NpyWriter


def test_written_rows_read_back(tmp_path):
    data = np.random.default_rng(0).integers(0, 255, (7, 4, 5, 3)).astype(np.uint8)
    writer = NpyWriter(tmp_path / "a.npy", data.shape, np.uint8)
    writer[0:3] = data[:3]
    writer[3:7] = data[3:]
    assert not (tmp_path / "a.npy").exists()  # only complete files get the final name
    writer.close()
    assert np.array_equal(np.load(tmp_path / "a.npy"), data)
    rows = NpyRows(tmp_path / "a.npy")
    assert len(rows) == 7 and rows.shape == data.shape
    assert np.array_equal(rows[2], data[2]) and np.array_equal(rows[-1], data[-1])
    assert np.array_equal(rows[1:5], data[1:5]) and rows[5:5].shape == (0, 4, 5, 3)
    with pytest.raises(IndexError):
        rows[7]


def test_rows_must_come_in_order_and_all_of_them(tmp_path):
    writer = NpyWriter(tmp_path / "b.npy", (4, 2), np.float16)
    with pytest.raises(IndexError, match="in order"):
        writer[1:2] = np.zeros((1, 2))
    writer[0:2] = np.ones((2, 2))
    with pytest.raises(ValueError, match="2 of 4 rows"):
        writer.close()
    assert not (tmp_path / "b.npy").exists()
