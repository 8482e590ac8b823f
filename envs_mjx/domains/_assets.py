"""Where the MJCF files live: `assets/` at the repository root, or `envs_mjx/assets` in a wheel."""

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parents[1]
# A wheel ships assets/ as the package data of `envs_mjx.assets` (pyproject.toml); a clone or
# an editable install reads the repository's own folder.
ASSETS = next((p for p in (_PACKAGE / "assets", _PACKAGE.parent / "assets")
               if (p / "PROVENANCE.md").is_file()), _PACKAGE.parent / "assets")


def asset(name: str) -> str:
    """Path of an MJCF file in assets/."""
    path = ASSETS / name
    if not path.is_file():
        raise FileNotFoundError(f"MJCF asset missing: {path} (reinstall jaml, or run from a "
                                "clone: assets/ ships in the wheel as envs_mjx/assets)")
    return str(path)
