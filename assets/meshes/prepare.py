"""Rebuilds assets/meshes/ from an unpacked pybullet 3.2.7 wheel (see assets/PROVENANCE.md).

python assets/meshes/prepare.py /path/to/unpacked/pybullet_data
"""

import sys
from pathlib import Path

import numpy as np
from PIL import Image

from envs_mjx.domains.mesh_object import TexturedMesh, decimate, read_obj, write_object

# name -> (obj, texture) inside pybullet_data. Both are modelled y-up; they are turned z-up.
SOURCES = {"duck": ("duck.obj", "duckCM.png"), "domino": ("domino/domino.obj", "domino/domino.jpg")}
Y_UP_TO_Z_UP = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], np.float64)


def main(pybullet_data: str) -> None:
    root = Path(pybullet_data)
    for name, (obj, tex) in SOURCES.items():
        verts, faces, uv = read_obj(root / obj)
        verts, faces, kept = decimate(verts @ Y_UP_TO_Z_UP.T, faces, 300)
        image = Image.open(root / tex).convert("RGB")
        image.thumbnail((128, 128), Image.Resampling.LANCZOS)
        mesh = TexturedMesh(verts, faces, uv[kept], np.asarray(image, np.uint8))
        write_object(mesh, Path(__file__).parent / name)
        print(name, len(verts), "vertices", len(faces), "faces", image.size)


if __name__ == "__main__":
    main(sys.argv[1])
