"""Input validation shared by the alignment and distortion measures (host-side, at the API edge)."""

from __future__ import annotations

import numpy as np


def as_matrix(name: str, x, min_rows: int = 1) -> np.ndarray:
    """Returns `x` as a finite float [N, F] host array, or raises ValueError naming `name`."""
    try:
        arr = np.asarray(x)
    except Exception as err:  # e.g. ragged nested lists
        raise ValueError(f"{name}: cannot be read as an array ({err})") from err
    if arr.ndim != 2:
        raise ValueError(f"{name}: expected a 2-D array [N, F], got shape {arr.shape}")
    if arr.dtype.kind != "f":
        raise ValueError(f"{name}: expected a floating-point dtype, got {arr.dtype}")
    if arr.shape[1] == 0:
        raise ValueError(f"{name}: has no feature columns (shape {arr.shape})")
    if arr.shape[0] < min_rows:
        raise ValueError(f"{name}: too few samples, need at least {min_rows}, got {arr.shape[0]}")
    bad = ~np.isfinite(arr)
    if bad.any():
        rows = np.unique(np.nonzero(bad)[0])
        raise ValueError(
            f"{name}: contains NaN or inf in {rows.size} row(s), first at row {int(rows[0])}"
        )
    return arr


def paired(names: tuple[str, str], x, y, min_rows: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Validates latents/states together: both [N, ·] floats with the same N ≥ `min_rows`."""
    a = as_matrix(names[0], x, min_rows=1)
    b = as_matrix(names[1], y, min_rows=1)
    if a.shape[0] != b.shape[0]:
        raise ValueError(
            f"{names[0]} and {names[1]} have mismatched N: {a.shape[0]} vs {b.shape[0]}"
        )
    if a.shape[0] < min_rows:
        raise ValueError(
            f"{names[0]}/{names[1]}: too few samples, need at least {min_rows}, got {a.shape[0]}"
        )
    return a, b
