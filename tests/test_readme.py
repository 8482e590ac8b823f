"""README's three usage snippets run as written (each marked `<!-- snippet: NAME -->`).

The encoder snippet runs in tests/test_suite_api.py, beside the smoke run whose compiled
programs it reuses (the same config: here it compiled them again, ~90 s on two cores); the
relations snippet in tests/relations/test_learning.py, beside the fixture that fits the same
relations."""

import re
from pathlib import Path

import numpy as np

README = (Path(__file__).resolve().parents[1] / "README.md").read_text()


def snippet(name: str) -> str:
    match = re.search(rf"<!-- snippet: {name}\b[^>]*-->\n```python\n(.*?)```", README, re.S)
    assert match, f"README has no snippet {name!r}"
    return match.group(1)


def test_readme_is_at_most_150_lines_and_links_install_and_status():
    assert len(README.splitlines()) <= 150
    for link in ("docs/install.md", "docs/status.md", "docs/own_learner.md",
                 "benchmarks/RESULTS.md", "docs/results/fig2.md", "docs/results/fig9.md"):
        assert f"]({link})" in README
        assert (Path(__file__).resolve().parents[1] / link).is_file()


def test_env_snippet_runs():
    namespace = {}
    exec(compile(snippet("env"), "README:env", "exec"), namespace)
    assert namespace["obs"].shape == (64, 64, 3) and namespace["state"].ld_state.shape == (4,)
    np.testing.assert_array_equal(namespace["state"].pixels.shape, (64, 64, 3))
