"""What the figure drivers share: reading run histories, table cells."""

from __future__ import annotations

import json
from pathlib import Path

from jaml.evaluation import plots


def read_history(path: Path) -> list[dict]:
    """The analysis records of a run's history.jsonl ([] when it has none yet)."""
    text = path.read_text() if path.exists() else ""
    return [json.loads(x) for x in text.splitlines() if x.strip()]


def cell(values, digits: int = 3) -> str:
    """'0.123' for one run, '0.123 ± 0.045' (90 % confidence half-width) for several."""
    mean, low, high = plots.mean_interval(values)
    if len(values) < 2:
        return f"{mean:.{digits}f}"
    return f"{mean:.{digits}f} ± {(high - low) / 2:.{digits}f}"
