"""benchmarks/regressor_fit.py times the analysis's fit: its row's errors are those
`alignment_errors_runs` gives for the same data, and its rate is its seconds per step."""

import numpy as np

from benchmarks import regressor_fit
from jaml.evaluation import alignment


def test_the_row_is_the_fit_of_its_data():
    tests = {"pi_rand": 16, "pi_curr": 8}
    (row,) = regressor_fit.bench(runs=2, train=40, tests=tests, iterations=3, repeats=1)
    sets = regressor_fit.data(2, {"train": 40, **tests}, 4)
    x, y = sets.pop("train")
    assert x.shape == (2, 40, 8) and y.shape == (2, 40, 4)  # latents Z = 2·D
    errors = alignment.alignment_errors_runs(x, y, sets, np.arange(2), num_iterations=3)
    assert row["errors_sha"] == regressor_fit.checksum(errors)
    assert row["pi_rand_error"] == float(np.mean(errors["pi_rand"]))
    assert row["us_per_step"] == 1e6 * row["seconds"] / 3 > 0
    assert row["impl"].startswith("jaml") and row["iterations"] == 3 and row["runs"] == 2
