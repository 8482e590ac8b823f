"""VAE_rpl's convolutions in each formulation, forward and backward: the frames' two layers (the
encoder's first convolution, 3 channels in, k4 s2 p1; the decoder's last transposed convolution,
3 out) and, with --layers middle, the wider layers between them.

    python benchmarks/conv_forms.py [--frames 1024] [--dtype bfloat16] [--reps 7] [--steps 20]
        [--layers frames middle]

cuDNN's tensor-core kernels take channels in multiples of 8, so these two layers, whose FLOPs are
a few percent of the step's, can cost far more than their bytes say. Each form computes the same
function (the test suite checks them against `lax`); this times each one's jitted value and
gradients (the kernel's; the input's too for the decoder layer, whose input is an activation),
steady state: median over `reps` blocked calls of `steps` steps each, compile apart.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness
from jaml.learners import networks

_HALVE = ((1, 1), (1, 1))
_NHWC = ("NHWC", "HWIO", "NHWC")


def _lax_conv(x, w):
    return jax.lax.conv_general_dilated(x, w, (2, 2), _HALVE, dimension_numbers=_NHWC)


def _patches_conv(x, w):
    """k4 s2 p1 as one matmul of the input's 4×4 patches."""
    c = x.shape[-1]
    patches = jax.lax.conv_general_dilated_patches(
        x, (4, 4), (2, 2), _HALVE, dimension_numbers=_NHWC)  # [N, H/2, W/2, C·16]
    k = w.transpose(2, 0, 1, 3).reshape(c * 16, -1)
    return patches @ k


FIRST = {  # [N, 64, 64, 3] × [4, 4, 3, 64] → [N, 32, 32, 64]
    "lax (3 channels)": _lax_conv,
    "2x2 blocks, k2 (conv2d off the CPU)": lambda x, w: networks.conv2d(
        x, w, (2, 2), _HALVE, cpu_kernels=False),
    "patches matmul": _patches_conv,
}
LAST = {  # [N, 32, 32, 64] × [4, 4, 64, 3] → [N, 64, 64, 3]
    **{f"upsample2x {f}": (lambda x, w, f=f: networks.upsample2x(x, w, form=f))
       for f in ("pair", "phase", "subpixel", "dilated")},
}
HALVING = {"lax": _lax_conv, "2x2 blocks, k2": networks._blocks_conv}  # the encoder's k4 s2 p1
# Per case: (layer, its forms, input shape less N, kernel shape, which gradients).
FRAMES = [("first layer", FIRST, (64, 64, 3), (4, 4, 3, 64), (1,)),
          ("last layer", LAST, (32, 32, 64), (4, 4, 64, 3), (0, 1))]
MIDDLE = [("conv1", HALVING, (32, 32, 64), (4, 4, 64, 128), (0, 1)),
          ("conv2", HALVING, (16, 16, 128), (4, 4, 128, 128), (0, 1)),
          ("conv3", HALVING, (8, 8, 128), (4, 4, 128, 256), (0, 1)),
          ("deconv1", LAST, (4, 4, 256), (4, 4, 256, 128), (0, 1)),
          ("deconv2", LAST, (8, 8, 128), (4, 4, 128, 128), (0, 1)),
          ("deconv3", LAST, (16, 16, 128), (4, 4, 128, 64), (0, 1))]


NOTES = ("The frames' two layers (the encoder's first convolution, 3 channels in; the decoder's "
         "last transposed convolution, 3 out) and the wider layers between them (conv1-3, "
         "deconv1-3) in each formulation: value and gradients, jitted, steady state "
         "(benchmarks/conv_forms.py).")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1024)
    parser.add_argument("--dtype", default="bfloat16")
    parser.add_argument("--reps", type=int, default=7)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--layers", nargs="+", default=["frames"], choices=["frames", "middle"])
    parser.add_argument("--no-record", action="store_true", help="print only")
    args = parser.parse_args(argv)
    dt, n = jnp.dtype(args.dtype), args.frames
    rng = np.random.default_rng(0)

    def normal(*shape):
        return jnp.asarray(rng.normal(size=shape), dt)

    cases = (FRAMES if "frames" in args.layers else []) + \
        (MIDDLE if "middle" in args.layers else [])
    rows = []
    for layer, forms, x_shape, w_shape, wrt in cases:
        args_ = (normal(n, *x_shape), normal(*w_shape))
        cotangent = None
        for name, f in forms.items():
            if cotangent is None:
                cotangent = normal(*jax.eval_shape(f, *args_).shape)
            rows.append(harness.form_row(f"{layer}, {n} frames, {args.dtype}", name, f, args_,
                                         cotangent, args.reps, args.steps, wrt))
    if not args.no_record:
        harness.record("conv_forms", rows, notes=NOTES)
    return 0


if __name__ == "__main__":
    sys.exit(main())
