"""DSA's recurrent layers in two forms, value and gradients: Flax's `nn.RNN` of its cells (both
matmuls at every step) against jaml's layers (`networks.LSTM`, `TanhRNN`: the inputs' projection
one matmul before the scan), the latter at several scan unrolls.

    python benchmarks/rnn_forms.py [--batch 42] [--steps-in-time 24] [--hidden 512]
        [--unrolls 1 2 4 8] [--reps 7] [--steps 20]

The layers and their input sizes are DSA's on CartPole at ld_dim 5 (static f and dynamic z of
5 each, one action; 128 conv features): the dynamic posterior's encoder (LSTMs both ways over
[f ⊕ features ⊕ a], then a tanh RNN), the static posterior's LSTM over half the steps, the
prior's LSTM over [z_{t-1} ⊕ f ⊕ a]. Both forms compute the same function (the test suite
checks them on the same parameters); this times each one's jitted value and its gradients for
the parameters and the inputs, steady state: median over `reps` blocked calls of `steps` steps
each, compile apart.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import flax.linen as nn
import jax

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness
from jaml.learners import networks

FEATURES, LATENT, ACTION = 128, 5, 1


class FlaxEncoder(nn.Module):
    """`networks.RNNEncoder` as Flax's cells scanned by `nn.RNN`."""

    hidden: int

    @nn.compact
    def __call__(self, x):
        init = networks.torch_rnn_init(self.hidden)
        cell = lambda: nn.OptimizedLSTMCell(self.hidden, kernel_init=init,  # noqa: E731
                                            recurrent_kernel_init=init, bias_init=init)
        both = nn.Bidirectional(nn.RNN(cell()), nn.RNN(cell()))(x)
        return nn.RNN(nn.SimpleCell(self.hidden, kernel_init=init, recurrent_kernel_init=init,
                                    bias_init=init))(both)


class FlaxLSTM(nn.Module):
    """`networks.LSTM` as Flax's `OptimizedLSTMCell` scanned by `nn.RNN`."""

    hidden: int

    @nn.compact
    def __call__(self, x):
        init = networks.torch_rnn_init(self.hidden)
        return nn.RNN(nn.OptimizedLSTMCell(self.hidden, kernel_init=init,
                                           recurrent_kernel_init=init, bias_init=init))(x)


def forms(hidden: int, unrolls: list[int]) -> dict[str, dict[str, nn.Module]]:
    """layer → form → module."""
    jaml_forms = lambda make: {f"hoisted, unroll {u}": make(u) for u in unrolls}  # noqa: E731
    return {
        "dynamic encoder": {"flax cells": FlaxEncoder(hidden),
                            **jaml_forms(lambda u: networks.RNNEncoder(hidden, u))},
        "static LSTM": {"flax cells": FlaxLSTM(hidden),
                        **jaml_forms(lambda u: networks.LSTM(hidden, unroll=u))},
        "prior LSTM": {"flax cells": FlaxLSTM(hidden),
                       **jaml_forms(lambda u: networks.LSTM(hidden, unroll=u))},
    }


NOTES = ("DSA's recurrent layers (dynamic encoder: LSTMs both ways then a tanh RNN; static and "
         "prior LSTMs) as Flax's nn.RNN of its cells against jaml's layers with the inputs' "
         "projection before the scan, at several unrolls: value and gradients (parameters and "
         "inputs), jitted, steady state (benchmarks/rnn_forms.py).")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=42)
    parser.add_argument("--steps-in-time", type=int, default=24)
    parser.add_argument("--hidden", type=int, default=512)
    parser.add_argument("--unrolls", type=int, nargs="+", default=[1, 2, 4, 8])
    parser.add_argument("--reps", type=int, default=7)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--no-record", action="store_true", help="print only")
    args = parser.parse_args(argv)
    b, t, h = args.batch, args.steps_in_time, args.hidden
    inputs = {"dynamic encoder": (b, t, LATENT + FEATURES + ACTION),
              "static LSTM": (b, t // 2, FEATURES),
              "prior LSTM": (b, t, 2 * LATENT + ACTION)}
    rows = []
    for layer, by_form in forms(h, args.unrolls).items():
        x = jax.random.normal(jax.random.key(0), inputs[layer])
        cotangent = jax.random.normal(jax.random.key(2), (b, x.shape[1], h))
        for name, module in by_form.items():
            params = module.init(jax.random.key(1), x)
            rows.append(harness.form_row(f"{layer}, {b} × {t}, hidden {h}", name, module.apply,
                                         (params, x), cotangent, args.reps, args.steps))
    if not args.no_record:
        harness.record("rnn_forms", rows, notes=NOTES)
    return 0


if __name__ == "__main__":
    sys.exit(main())
