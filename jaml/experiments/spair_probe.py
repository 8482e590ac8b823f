"""Does SPAIR find objects? A toy task and its measures (`python -m jaml.experiments.spair_probe`).

Synthetic 64×64 frames with 1–4 coloured squares and discs at random, non-overlapping positions
on a plain or lightly textured background of a random dark colour, trained through the shared
train step on a fresh batch each step. Measured on held-out frames from the posterior means
(BatchNorm in eval mode): mean presence on the cells that hold an object's centre and on the
others, and, for the present cells (presence > ½), the distance of the box centre to the
nearest true object's centre (in cells) and the IoU with that object's box.
Shapes: B frames, M = `MAX_OBJECTS` object slots, N = G² cells.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time

import jax
import numpy as np
from PIL import Image

from jaml import learners
from jaml.learners import spair

FRAME = 64
MAX_OBJECTS = 4

# A narrow SPAIR that trains in minutes on two CPU cores (4×4 grid, 16×16 glimpses).
SMALL = {"backbone_filters": (16, 32, 64), "conv_features": 64, "lateral_widths": (64,),
         "passthrough": 32, "glimpse_size": 16, "what_dim": 8, "object_filters": (16, 32),
         "object_hidden": 64, "bg_hidden": 32}


@dataclasses.dataclass(frozen=True)
class Scene:
    """Toy frames and their objects: frames uint8 [B, 1, 64, 64, 3]; boxes [B, M, 4] pixel
    edges (x0, y0, x1, y1); valid bool [B, M] (the first n slots of a frame with n objects)."""

    frames: np.ndarray
    boxes: np.ndarray
    valid: np.ndarray


def toy_scenes(rng: np.random.Generator, b: int, texture: float = 0.05,
               sizes: tuple[int, int] = (10, 16), max_objects: int = MAX_OBJECTS) -> Scene:
    """b frames of 1..max_objects squares or discs, sides in `sizes` (pixels, inclusive).

    The background is a dark colour (each channel in [0, 0.3]) plus, if texture > 0, a smooth
    random pattern of amplitude `texture`; objects are bright (each channel in [0.5, 1]) and
    do not overlap (their boxes are ≥ 2 pixels apart).
    """
    yy, xx = np.mgrid[0:FRAME, 0:FRAME] + 0.5
    frames = np.empty((b, FRAME, FRAME, 3))
    boxes = np.zeros((b, max_objects, 4))
    valid = np.zeros((b, max_objects), bool)
    for i in range(b):
        frames[i] = rng.uniform(0.0, 0.3, size=3)
        if texture > 0:
            k = rng.uniform(1.0, 3.0, size=(2, 2)) * 2 * np.pi / FRAME
            phase = rng.uniform(0, 2 * np.pi, size=(2, 3))
            for j in range(2):
                frames[i] += texture * 0.5 * np.sin(k[j, 0] * xx + k[j, 1] * yy
                                                    + phase[j][:, None, None]).transpose(1, 2, 0)
        placed = []
        for _ in range(int(rng.integers(1, max_objects + 1))):
            for _try in range(50):
                s = int(rng.integers(sizes[0], sizes[1] + 1))
                x0, y0 = (int(v) for v in rng.integers(0, FRAME - s + 1, size=2))
                box = (x0, y0, x0 + s, y0 + s)
                if all(box[0] >= q[2] + 2 or q[0] >= box[2] + 2 or box[1] >= q[3] + 2
                       or q[1] >= box[3] + 2 for q in placed):
                    break
            else:
                continue
            colour = rng.uniform(0.5, 1.0, size=3)
            if rng.random() < 0.5:
                mask = np.zeros((FRAME, FRAME), bool)
                mask[y0:y0 + s, x0:x0 + s] = True
            else:
                cx, cy = x0 + s / 2, y0 + s / 2
                mask = (xx - cx) ** 2 + (yy - cy) ** 2 <= (s / 2) ** 2
            frames[i][mask] = colour
            boxes[i, len(placed)] = box
            valid[i, len(placed)] = True
            placed.append(box)
    frames = (np.clip(frames, 0.0, 1.0) * 255).round().astype(np.uint8)[:, None]
    return Scene(frames, boxes, valid)


def iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """[...]: IoU of boxes a, b [..., 4] (x0, y0, x1, y1), broadcasting."""
    w = np.clip(np.minimum(a[..., 2], b[..., 2]) - np.maximum(a[..., 0], b[..., 0]), 0, None)
    h = np.clip(np.minimum(a[..., 3], b[..., 3]) - np.maximum(a[..., 1], b[..., 1]), 0, None)
    area = lambda x: (x[..., 2] - x[..., 0]) * (x[..., 3] - x[..., 1])  # noqa: E731
    inter = w * h
    return inter / np.maximum(area(a) + area(b) - inter, 1e-9)


def object_metrics(box_px: np.ndarray, presence: np.ndarray, scene: Scene, grid: int,
                   threshold: float = 0.5) -> dict[str, float]:
    """Presence on object / empty cells and the present boxes against the true objects.

    box_px [B, N, 4] pixel boxes, presence [B, N] probabilities (cells row-major), scene's
    objects. A cell is an object cell if an object's centre lies in it. Returns
    pres_object / pres_empty: mean presence over object / empty cells; n_present / n_true:
    mean count per frame of present cells / objects; centre_err: mean distance (cells) from a
    present box's centre to the nearest object's centre; iou: mean IoU of a present box with
    that object; recall: the share of objects with a present box of IoU > ½ (NaN where there
    is no present box).
    """
    box_px, presence = np.asarray(box_px, np.float64), np.asarray(presence, np.float64)
    b, n = presence.shape
    cell = FRAME / grid
    centres = (scene.boxes[..., :2] + scene.boxes[..., 2:]) / 2  # [B, M, 2] (x, y)
    col = np.clip((centres[..., 0] // cell).astype(int), 0, grid - 1)
    row = np.clip((centres[..., 1] // cell).astype(int), 0, grid - 1)
    occupied = np.zeros((b, n), bool)
    for i, m in zip(*np.nonzero(scene.valid), strict=True):
        occupied[i, row[i, m] * grid + col[i, m]] = True
    present = presence > threshold
    pred_centres = (box_px[..., :2] + box_px[..., 2:]) / 2  # [B, N, 2]
    dist = np.linalg.norm(pred_centres[:, :, None] - centres[:, None], axis=-1) / cell  # [B,N,M]
    dist = np.where(scene.valid[:, None], dist, np.inf)
    nearest = np.argmin(dist, axis=-1)  # [B, N]
    overlap = iou(box_px[:, :, None], scene.boxes[:, None])  # [B, N, M]
    matched_iou = np.take_along_axis(overlap, nearest[..., None], -1)[..., 0]
    hit = np.any(present[..., None] & (overlap > 0.5), axis=1)  # [B, M]
    nan = float("nan")
    return {
        "pres_object": float(presence[occupied].mean()),
        "pres_empty": float(presence[~occupied].mean()),
        "n_present": float(present.sum(axis=1).mean()),
        "n_true": float(scene.valid.sum(axis=1).mean()),
        "centre_err": float(np.min(dist, axis=-1)[present].mean()) if present.any() else nan,
        "iou": float(matched_iou[present].mean()) if present.any() else nan,
        "recall": float(hit[scene.valid].mean()),
    }


def train(overrides: dict | None = None, steps: int = 2000, batch: int = 16, seed: int = 0,
          eval_every: int = 100, eval_frames: int = 64, texture: float = 0.05, log=None):
    """Train SPAIR (`SMALL` updated by `overrides`) on fresh toy batches; evaluate every
    `eval_every` steps and at the end on `eval_frames` held-out frames.

    Returns (learner, final TrainState, held-out Scene, history: a list of dicts with the
    step, the mean training metrics since the last evaluation and `object_metrics`). `log`,
    if given, is called with each history entry.
    """
    config = {**SMALL, **(overrides or {})}
    learner = learners.make("SPAIR", ld_dim=2, **config)
    opt = learners.default_optimizer(learner)
    rng = np.random.default_rng(seed)
    held_out = toy_scenes(np.random.default_rng(10_000 + seed), eval_frames, texture)
    actions = np.zeros((batch, 1, 1), np.float32)
    first = toy_scenes(rng, batch, texture)
    state = learners.init_train_state(learner, opt, jax.random.key(seed), (first.frames, actions))
    step_fn = jax.jit(learners.make_train_step(learner, opt),
                      compiler_options=learners.compiler_options())
    boxes_fn = jax.jit(learner.boxes)
    history, sums, count, t0 = [], {}, 0, time.perf_counter()
    scene = first
    for i in range(1, steps + 1):
        state, metrics = step_fn(state, (scene.frames, actions), jax.random.fold_in(
            jax.random.key(seed), i))
        for k, v in jax.device_get(metrics).items():
            sums[k] = sums.get(k, 0.0) + float(v)
        count += 1
        scene = toy_scenes(rng, batch, texture)
        if i % eval_every == 0 or i == steps:
            box_px, presence = jax.device_get(boxes_fn(state.variables, held_out.frames[:, 0]))
            entry = {"step": i, "seconds": round(time.perf_counter() - t0, 1),
                     **{k: v / count for k, v in sums.items()},
                     **object_metrics(box_px, presence, held_out, learner.config.grid_size)}
            history.append(entry)
            sums, count = {}, 0
            if log is not None:
                log(entry)
    return learner, state, held_out, history


def picture(learner, variables, scene: Scene, count: int = 8) -> np.ndarray:
    """uint8 [2·64, count·64, 3]: the true frames (top) and the reconstructions (bottom), both
    with the boxes of the present cells (presence > ½) in red."""
    frames = scene.frames[:count, 0]
    recon = np.asarray(jax.jit(learner.reconstruct)(variables, scene.frames[:count],
                                                    np.zeros((count, 1, 1), np.float32)))
    recon = (np.clip(recon[:, 0], 0, 1) * 255).round().astype(np.uint8)
    box_px, presence = jax.device_get(jax.jit(learner.boxes)(variables, frames))
    rows = [spair.draw_boxes(f, box_px, presence) for f in (frames, recon)]
    return np.concatenate([np.concatenate(list(r), axis=1) for r in rows], axis=0)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--eval-every", type=int, default=100)
    parser.add_argument("--texture", type=float, default=0.05)
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=JSON",
                        help="a SPAIRConfig override, e.g. --set training_wheels_steps=500")
    parser.add_argument("--png", default=None, help="write reconstructions with boxes here")
    parser.add_argument("--json", default=None, help="write the history here")
    args = parser.parse_args(argv)
    overrides = {}
    for item in args.set:
        key, value = item.split("=", 1)
        value = json.loads(value)
        overrides[key] = tuple(value) if isinstance(value, list) else value
    print(json.dumps({"overrides": overrides, "steps": args.steps, "batch": args.batch,
                      "seed": args.seed, "texture": args.texture}), flush=True)
    keys = ("step", "seconds", "loss", "nll", "pres", "bg", "pres_object", "pres_empty",
            "n_present", "n_true", "centre_err", "iou", "recall")

    def log(entry):
        print(" ".join(f"{k}={entry[k]:.4g}" if isinstance(entry[k], float) else
                       f"{k}={entry[k]}" for k in keys if k in entry), flush=True)

    learner, state, held_out, history = train(overrides, args.steps, args.batch, args.seed,
                                              args.eval_every, texture=args.texture, log=log)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"overrides": overrides, "batch": args.batch, "seed": args.seed,
                       "history": history}, f, indent=1)
    if args.png:
        Image.fromarray(picture(learner, state.variables, held_out)).save(args.png)
    return history


if __name__ == "__main__":
    main(sys.argv[1:])
