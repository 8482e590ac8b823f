"""Textured object meshes for MeshOnIncline: read a YCB google_16k-style folder, decimate, shrink.

A folder holds `textured.obj` (triangles or polygons with `vt` texture coordinates) and
`texture_map.png`, the layout the YCB dataset ships. `load_object` returns the mesh decimated
to at most `max_faces` triangles (vertex clustering, `envs_mjx.render.decimate`; the surviving
faces keep their original corner uvs) and the texture shrunk to at most `max_texture` pixels a
side, with the object re-centred on its bounding box and scaled so its longest side is `size` m.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from PIL import Image

from envs_mjx.render import decimate

OBJ_NAME = "textured.obj"
TEXTURE_NAME = "texture_map.png"


@dataclasses.dataclass(frozen=True)
class TexturedMesh:
    """verts [V, 3] m; faces [F, 3] int; uv [F, 3, 2] per-corner texture coordinates (OBJ
    convention: v = 0 at the image's bottom row); texture uint8 [H, W, 3]."""

    verts: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    texture: np.ndarray


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(verts [V, 3], faces [F, 3], uv [F, 3, 2]) of an OBJ with texture coordinates.

    Polygons are fanned into triangles. Raises ValueError when the file has no faces or a face
    corner lacks a texture coordinate.
    """
    verts, tcoords, faces, face_tc = [], [], [], []
    for n, line in enumerate(Path(path).read_text().splitlines(), 1):
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            verts.append([float(x) for x in parts[1:4]])
        elif parts[0] == "vt":
            tcoords.append([float(x) for x in parts[1:3]])
        elif parts[0] == "f":
            corners = [c.split("/") for c in parts[1:]]
            if any(len(c) < 2 or not c[1] for c in corners):
                raise ValueError(f"{path}:{n}: face corner without a texture coordinate")
            vi = [_index(c[0], len(verts)) for c in corners]
            ti = [_index(c[1], len(tcoords)) for c in corners]
            for k in range(1, len(corners) - 1):
                faces.append([vi[0], vi[k], vi[k + 1]])
                face_tc.append([ti[0], ti[k], ti[k + 1]])
    if not faces:
        raise ValueError(f"{path}: no faces")
    tc = np.asarray(tcoords, np.float64)
    return np.asarray(verts, np.float64), np.asarray(faces, np.int64), tc[np.asarray(face_tc)]


def _index(token: str, count: int) -> int:
    i = int(token)
    return i - 1 if i > 0 else count + i  # OBJ indices are 1-based; negative ones count back


def load_object(
    folder: str | Path, size: float, max_faces: int = 300, max_texture: int = 128
) -> TexturedMesh:
    """The textured object in `folder` (see the module docstring), decimated and rescaled."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"object folder not found: {folder}")
    obj, png = folder / OBJ_NAME, folder / TEXTURE_NAME
    for f in (obj, png):
        if not f.is_file():
            raise FileNotFoundError(
                f"{f} missing: an object folder holds {OBJ_NAME} and {TEXTURE_NAME} "
                "(the YCB google_16k layout)"
            )
    verts, faces, uv = read_obj(obj)
    verts, faces, kept = decimate(verts, faces, max_faces)
    uv = uv[kept]
    lo, hi = verts.min(0), verts.max(0)
    verts = (verts - (lo + hi) / 2) * (size / float(np.max(hi - lo)))
    image, uv = crop_to_uv(Image.open(png).convert("RGB"), uv)
    image.thumbnail((max_texture, max_texture), Image.Resampling.LANCZOS)
    return TexturedMesh(verts, faces, uv, np.asarray(image, np.uint8))


def crop_to_uv(image, uv: np.ndarray):
    """(image cropped to the texels the faces use, uv remapped to it), so that shrinking keeps
    detail when a texture is an atlas (the domino's image holds a whole set of tiles). Tiling
    uvs (outside [0, 1]) leave both unchanged. image: a PIL image; uv [F, 3, 2], OBJ convention."""
    if uv.min() < 0.0 or uv.max() > 1.0:
        return image, uv
    w, h = image.size
    u, v = uv[..., 0], uv[..., 1]
    left, right = int(np.floor(u.min() * w)), int(np.ceil(u.max() * w))
    top, bottom = int(np.floor((1.0 - v.max()) * h)), int(np.ceil((1.0 - v.min()) * h))
    right, bottom = max(right, left + 1), max(bottom, top + 1)
    new_u = (u * w - left) / (right - left)
    new_v = 1.0 - ((1.0 - v) * h - top) / (bottom - top)
    return image.crop((left, top, right, bottom)), np.stack([new_u, new_v], axis=-1)


def write_object(mesh: TexturedMesh, folder: str | Path) -> None:
    """Writes `mesh` as `folder/textured.obj` + `texture_map.png` (what `load_object` reads)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    lines = [f"v {x:.6g} {y:.6g} {z:.6g}" for x, y, z in mesh.verts]
    lines += [f"vt {u:.5g} {v:.5g}" for u, v in mesh.uv.reshape(-1, 2)]
    for i, (a, b, c) in enumerate(mesh.faces + 1):
        t = 3 * i + 1
        lines.append(f"f {a}/{t} {b}/{t + 1} {c}/{t + 2}")
    (folder / OBJ_NAME).write_text("\n".join(lines) + "\n")
    Image.fromarray(mesh.texture).save(folder / TEXTURE_NAME, optimize=True)
