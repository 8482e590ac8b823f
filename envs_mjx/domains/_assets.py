"""Where the MJCF files live: `assets/` at the repository root."""

from pathlib import Path

ASSETS = Path(__file__).resolve().parents[2] / "assets"


def asset(name: str) -> str:
    """Path of an MJCF file in assets/."""
    path = ASSETS / name
    if not path.is_file():
        raise FileNotFoundError(f"MJCF asset missing: {path}")
    return str(path)
