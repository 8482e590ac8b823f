"""Rebuilds assets/meshes/ from an unpacked pybullet 3.2.7 wheel (see assets/PROVENANCE.md).

python assets/meshes/prepare.py /path/to/unpacked/pybullet_data
"""

import sys
from pathlib import Path

import numpy as np
from PIL import Image

from envs_mjx.domains.mesh_object import (
    TexturedMesh,
    crop_to_uv,
    decimate,
    read_obj,
    write_object,
)

# Turns from the models' y-up to z-up: the duck about +x, the domino about -x (so its dotted face,
# at -y in the OBJ, faces up).
Y_UP_TO_Z_UP = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], np.float64)
Y_DOWN_TO_Z_UP = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], np.float64)
# name -> (obj, texture, rotation) inside pybullet_data.
SOURCES = {
    "duck": ("duck.obj", "duckCM.png", Y_UP_TO_Z_UP),
    "domino": ("domino/domino.obj", "domino/domino.jpg", Y_DOWN_TO_Z_UP),
}


def main(pybullet_data: str) -> None:
    root = Path(pybullet_data)
    for name, (obj, tex, rotation) in SOURCES.items():
        verts, faces, uv = read_obj(root / obj)
        verts, faces, kept = decimate(verts @ rotation.T, faces, 300)
        image, uv_kept = crop_to_uv(Image.open(root / tex).convert("RGB"), uv[kept])
        image.thumbnail((128, 128), Image.Resampling.LANCZOS)
        mesh = TexturedMesh(verts, faces, uv_kept, np.asarray(image, np.uint8))
        write_object(mesh, Path(__file__).parent / name)
        print(name, len(verts), "vertices", len(faces), "faces", image.size)


if __name__ == "__main__":
    main(sys.argv[1])
