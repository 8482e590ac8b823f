"""A user's own on-manifold rows: a `.npy` or `.csv` file of [N, D] rows as a `Source`."""

from __future__ import annotations

import csv
import dataclasses
import hashlib
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

SUFFIXES = (".npy", ".csv")


def _float(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def _read_csv(path: Path) -> tuple[np.ndarray, tuple[str, ...]]:
    """Rows and column names of a CSV file; the first row is a header when any of its cells
    is not a number. Cells are separated by commas, or by semicolons or tabs when the first
    line has those and no comma (read as one cell, "1;2;3" made a header of the first line)."""
    with path.open(newline="") as f:
        text = f.read()
    first = next((line for line in text.splitlines() if line.strip()), "")
    delimiter = next((d for d in ";\t" if d in first), ",") if "," not in first else ","
    lines = [row for row in csv.reader(text.splitlines(), delimiter=delimiter)
             if any(cell.strip() for cell in row)]
    if not lines:
        raise ValueError(f"{path}: the file is empty")
    names: tuple[str, ...] = ()
    if any(_float(cell) is None for cell in lines[0]):
        names = tuple(cell.strip() for cell in lines[0])
        lines = lines[1:]
        if len(set(names)) != len(names) or not all(names):
            raise ValueError(f"{path}: the header's column names must be distinct and non-empty, "
                             f"got {list(names)}")
    width = len(names) if names else len(lines[0]) if lines else 0
    rows = []
    for number, row in enumerate(lines, start=2 if names else 1):
        if len(row) != width:
            raise ValueError(f"{path}: line {number} has {len(row)} columns, expected {width}")
        values = [_float(cell) for cell in row]
        bad = next((cell for cell, v in zip(row, values, strict=True) if v is None), None)
        if bad is not None:
            raise ValueError(f"{path}: line {number}: {bad.strip()!r} is not a number")
        rows.append(values)
    return np.asarray(rows, np.float64).reshape(len(rows), width), names


def _check(rows: np.ndarray, path: Path) -> np.ndarray:
    """[N, D] finite floats with N ≥ 2 and D ≥ 1, or a ValueError naming the problem."""
    if rows.ndim != 2:
        raise ValueError(f"{path}: expected an array of [N, D] rows, got shape {rows.shape}")
    if not (np.issubdtype(rows.dtype, np.floating) or np.issubdtype(rows.dtype, np.integer)):
        raise ValueError(f"{path}: expected numbers, got dtype {rows.dtype}")
    if rows.shape[0] < 2 or rows.shape[1] < 1:
        raise ValueError(f"{path}: expected at least 2 rows of at least 1 column, got shape "
                         f"{rows.shape}")
    bad = ~np.isfinite(rows)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise ValueError(f"{path}: {int(bad.sum())} non-finite values (NaN/inf), the first in "
                         f"row {row} (0-based, after any header), column {col}")
    return rows.astype(np.float32)


@dataclasses.dataclass(frozen=True, eq=False)
class FileSource:
    """The rows of a `.npy` ([N, D] array) or `.csv` (N lines of D numbers, optionally after a
    header line of column names) file.

    `pool_size` is N, so `relations.fit` reads every row once and trains on them as data;
    `sample(key, n)` draws n rows without replacement (with replacement when n > N).
    Columns are named by the CSV header, else x0, x1, …
    """

    path: Path
    rows: np.ndarray = dataclasses.field(repr=False)
    names: tuple[str, ...] = ()

    @classmethod
    def load(cls, path) -> FileSource:
        path = Path(path)
        if path.suffix.lower() not in SUFFIXES:
            raise ValueError(f"{path}: expected a .npy or .csv file of [N, D] rows")
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such file")
        if path.suffix.lower() == ".npy":
            try:
                rows, names = np.load(path, allow_pickle=False), ()
            except ValueError as error:
                raise ValueError(f"{path}: not a numeric .npy array ({error})") from None
        else:
            rows, names = _read_csv(path)
        rows = _check(np.asarray(rows), path)
        if names and len(names) != rows.shape[1]:
            raise ValueError(f"{path}: {len(names)} column names for {rows.shape[1]} columns")
        return cls(path, rows, names)

    @property
    def name(self) -> str:
        return str(self.path)

    @property
    def dim_names(self) -> tuple[str, ...]:
        return self.names or tuple(f"x{i}" for i in range(self.rows.shape[1]))

    @property
    def pool_size(self) -> int:
        return int(self.rows.shape[0])

    def fingerprint(self) -> str:
        """SHA-256 of the rows and names: a resumed run checks that the data is the same."""
        digest = hashlib.sha256(np.ascontiguousarray(self.rows).tobytes())
        digest.update(repr((self.rows.shape, self.dim_names)).encode())
        return digest.hexdigest()

    def sample(self, key: jax.Array, n: int) -> jax.Array:
        rows = jnp.asarray(self.rows)
        count = rows.shape[0]
        if n <= count:
            return rows[jax.random.permutation(key, count)[:n]]
        return rows[jax.random.randint(key, (n,), 0, count)]
