"""The `jaml` console script (pyproject's `[project.scripts]`): `jaml.cli.main`.

`--help` needs no cache: building any command's help imports tyro and the config dataclasses,
none of which imports JAX, MJX, Flax or MuJoCo (tests/test_launch.py checks it).
"""

from __future__ import annotations

import sys

from jaml import cli


def main(argv: list[str] | None = None) -> int:
    return cli.main(argv)


if __name__ == "__main__":
    sys.exit(main())
