"""Stream long arrays to and from .npy files without mapping them into memory.

A memory map keeps every page it has touched in the process's resident memory, so reading or
writing a 30-minute video's frames through one grows with the video. These read and write rows
through a file handle instead; the files are ordinary .npy files (np.load reads them).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np


class NpyRows(Sequence):
    """Rows of a .npy file (C order), read on demand: rows[i] or rows[a:b]."""

    def __init__(self, path: Path):
        self.path = Path(path)
        with self.path.open("rb") as handle:
            version = np.lib.format.read_magic(handle)
            read = {(1, 0): np.lib.format.read_array_header_1_0,
                    (2, 0): np.lib.format.read_array_header_2_0}.get(version)
            if read is None:
                raise ValueError(f"{path}: unsupported .npy version {version}")
            shape, fortran, dtype = read(handle)
            self.offset = handle.tell()
        if fortran or not shape:
            raise ValueError(f"{path}: expected a C-ordered array with rows")
        self.shape, self.dtype = shape, dtype
        self.row_items = int(np.prod(shape[1:], dtype=np.int64))

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, index):
        if isinstance(index, slice):
            start, stop, step = index.indices(len(self))
            if step != 1:
                raise IndexError("NpyRows reads contiguous rows only")
            return self._read(start, max(stop - start, 0))
        index = int(index) + (len(self) if index < 0 else 0)
        if not 0 <= index < len(self):
            raise IndexError(f"row {index} of {len(self)}")
        return self._read(index, 1)[0]

    def _read(self, start: int, count: int) -> np.ndarray:
        with self.path.open("rb") as handle:
            handle.seek(self.offset + start * self.row_items * self.dtype.itemsize)
            data = np.fromfile(handle, dtype=self.dtype, count=count * self.row_items)
        return data.reshape((count, *self.shape[1:]))


class NpyWriter:
    """Writes an (N, ...) .npy file row block by row block, in order, under a temporary name;
    `close` renames it to its final name once every row is written."""

    def __init__(self, path: Path, shape: tuple[int, ...], dtype):
        self.path = Path(path)
        self.tmp = self.path.with_name(self.path.name + ".partial.npy")
        self.shape, self.dtype, self.written = shape, np.dtype(dtype), 0
        self.handle = self.tmp.open("wb")
        np.lib.format.write_array_header_2_0(self.handle, {
            "descr": np.lib.format.dtype_to_descr(self.dtype), "fortran_order": False,
            "shape": shape})

    def __setitem__(self, index: slice, rows: np.ndarray) -> None:
        start, stop, _ = index.indices(self.shape[0])
        if start != self.written or stop - start != len(rows):
            raise IndexError(f"{self.path}: rows must be written in order (next {self.written})")
        self.handle.write(np.ascontiguousarray(rows, dtype=self.dtype).tobytes())
        self.written = stop

    def discard(self) -> None:
        """Close and delete the temporary file (the writing failed)."""
        self.handle.close()
        self.tmp.unlink(missing_ok=True)

    def close(self) -> Path:
        self.handle.close()
        if self.written != self.shape[0]:
            raise ValueError(f"{self.path}: {self.written} of {self.shape[0]} rows written")
        os.replace(self.tmp, self.path)
        return self.path
