"""The alignment regressor's fit as the reference suite runs it, in PyTorch: one MLP per run,
fit in turn (`analyze_hsz` 256, 256, ReLU + dropout 0.2, Adam, L1 on random minibatches), the
peer of `jaml.evaluation.alignment.alignment_errors_runs` for benchmarks/regressor_fit.py.
Settings come from jaml's `RegressorConfig`, so both sides fit the same problem."""

from __future__ import annotations

import numpy as np


def fit_runs(x, y, tests: dict, seeds, config, device) -> dict[str, np.ndarray]:
    """Each run's fit and its mean |error| per target on each test set (and the held-out
    rows): x [R, N, Z], y [R, N, D] numpy, tests {name: (x, y)} → {name: [R, D]}."""
    import torch

    errors: dict[str, list] = {name: [] for name in [*tests, "validation"]}
    for r, seed in enumerate(seeds):
        torch.manual_seed(int(seed))
        xs, ys = (torch.as_tensor(a[r], device=device) for a in (x, y))
        n_val = config.split(len(xs))
        x_fit, y_fit = xs[n_val:], ys[n_val:]
        mean, std = y_fit.mean(0), y_fit.std(0, unbiased=False) + config.std_eps
        layers, width = [], xs.shape[1]
        for h in config.hidden:
            layers += [torch.nn.Linear(width, h), torch.nn.ReLU(), torch.nn.Dropout(config.dropout)]
            width = h
        model = torch.nn.Sequential(*layers, torch.nn.Linear(width, ys.shape[1])).to(device)
        opt = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
        target = (y_fit - mean) / std
        batch = config.batch_for(len(x_fit))
        model.train()
        for _ in range(config.num_iterations):
            idx = torch.randint(len(x_fit), (batch,), device=device)
            loss = (model(x_fit[idx]) - target[idx]).abs().mean()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
        model.eval()
        with torch.no_grad():
            sets = {name: tuple(torch.as_tensor(a[r], device=device) for a in pair)
                    for name, pair in tests.items()} | {"validation": (xs[:n_val], ys[:n_val])}
            for name, (xt, yt) in sets.items():
                errors[name].append((model(xt) - (yt - mean) / std).abs().mean(0).cpu().numpy())
    return {name: np.stack(rows) for name, rows in errors.items()}
