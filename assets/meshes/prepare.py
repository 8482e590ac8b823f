"""Rebuilds assets/meshes/ and assets/textures/ from two unpacked PyPI wheels (PROVENANCE.md).

python assets/meshes/prepare.py PYBULLET_DATA ROBOSUITE_ASSETS
python assets/meshes/prepare.py --panda ROBOSUITE_ASSETS    (only meshes/panda/)

PYBULLET_DATA: `pybullet_data/` of the pybullet 3.2.7 wheel; ROBOSUITE_ASSETS:
`robosuite/models/assets/` of the robosuite 1.5.2 wheel (`pip download --no-deps` each, unzip).
Objects are turned z-up with the pose they rest in on the plank (MeshOnIncline lays a mesh with its
+z away from the plank and its +x downhill), decimated to at most 300 triangles and given a
texture of at most 128 px a side; surface textures (the plank and ground pairs) are shrunk to
64 px a side, which is finer than a 64 x 64 frame resolves on either surface.
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

ASSETS = Path(__file__).resolve().parents[1]
# Rotations (applied to the OBJ's vertices) into the z-up pose the object rests in.
# The duck: y-up model, turned about +x. The domino: turned about -x so its dotted face (at -y in
# the OBJ) faces up.
Y_UP_TO_Z_UP = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], np.float64)
Y_DOWN_TO_Z_UP = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], np.float64)
# robosuite's objects are z-up and upright. The cereal box lies on its printed front (-y of the
# OBJ faces up) with its long side (z) downhill; the can lies on its side, axis downhill, as the
# reference's YCB boxes and cans did (their long axis pointed downhill at reset).
BOX_ON_FRONT = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], np.float64)
ON_SIDE = np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], np.float64)
IDENTITY = np.eye(3)
# name -> (wheel, obj, texture, rotation); wheel is "pybullet" or "robosuite".
OBJECTS = {
    "duck": ("pybullet", "duck.obj", "duckCM.png", Y_UP_TO_Z_UP),
    "domino": ("pybullet", "domino/domino.obj", "domino/domino.jpg", Y_DOWN_TO_Z_UP),
    "cereal": ("robosuite", "objects/meshes/cereal.obj", "textures/cereal.png", BOX_ON_FRONT),
    "can": ("robosuite", "objects/meshes/can.obj", "textures/soda.png", ON_SIDE),
    "bread": ("robosuite", "objects/meshes/bread.obj", "textures/bread.png", IDENTITY),
    "lemon": ("robosuite", "objects/meshes/lemon.obj", "textures/lemon.png", IDENTITY),
}
# Surface textures for the plank / ground pairs (envs_mjx.domains.mesh_incline.SURFACES):
# file name in assets/textures/ -> texture in robosuite's `textures/`.
SURFACES = (
    "clay",
    "red-wood",
    "blue-wood",
    "cream-plaster",
    "light-gray-floor-tile",
    "light-wood",
    "wood-varnished-panels",
    "green-wood",
    "dirt",
    "gray-woodgrain",
    "brass-ambra",
    "dark-wood",
)
SURFACE_SIZE = 64
# The Franka Panda's links (Rearrange-Franka): the collision meshes of franka_ros'
# panda_description that robosuite ships under `bullet_data/`, in each link's URDF frame (m).
PANDA_DIR = "bullet_data/panda_description/meshes/collision"
PANDA_LINKS = ("link0", "link1", "link2", "link3", "link4", "link5", "link6", "link7", "hand",
               "finger")
PANDA_MAX_FACES = 120


def read_stl(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(verts [V, 3], faces [F, 3]) of a binary STL, corners shared between triangles welded."""
    raw = path.read_bytes()
    n = int(np.frombuffer(raw[80:84], np.uint32)[0])
    rec = np.dtype([("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    corners = np.frombuffer(raw[84 : 84 + 50 * n], rec)["v"].reshape(-1, 3).astype(np.float64)
    verts, index = np.unique(np.round(corners, 6), axis=0, return_inverse=True)
    return verts, index.reshape(-1, 3)


def prepare_panda(robosuite_assets: str) -> None:
    """meshes/panda/<link>.obj: each link's collision mesh decimated to PANDA_MAX_FACES."""
    out = ASSETS / "meshes" / "panda"
    out.mkdir(parents=True, exist_ok=True)
    for link in PANDA_LINKS:
        verts, faces = read_stl(Path(robosuite_assets) / PANDA_DIR / f"{link}.stl")
        verts, faces, _ = decimate(verts, faces, PANDA_MAX_FACES)
        used, faces = np.unique(faces, return_inverse=True)
        verts, faces = verts[used], faces.reshape(-1, 3)
        lines = [f"v {x:.5f} {y:.5f} {z:.5f}" for x, y, z in verts]
        lines += [f"f {a} {b} {c}" for a, b, c in faces + 1]
        (out / f"{link}.obj").write_text("\n".join(lines) + "\n")
        print(link, len(verts), "vertices", len(faces), "faces")


def prepare_object(path_obj: Path, path_tex: Path, rotation: np.ndarray) -> TexturedMesh:
    verts, faces, uv = read_obj(path_obj)
    verts, faces, kept = decimate(verts @ rotation.T, faces, 300)
    image, uv_kept = crop_to_uv(Image.open(path_tex).convert("RGB"), uv[kept])
    image.thumbnail((128, 128), Image.Resampling.LANCZOS)
    return TexturedMesh(verts, faces, uv_kept, np.asarray(image, np.uint8))


def main(pybullet_data: str, robosuite_assets: str) -> None:
    roots = {"pybullet": Path(pybullet_data), "robosuite": Path(robosuite_assets)}
    for name, (wheel, obj, tex, rotation) in OBJECTS.items():
        mesh = prepare_object(roots[wheel] / obj, roots[wheel] / tex, rotation)
        write_object(mesh, ASSETS / "meshes" / name)
        extent = np.ptp(mesh.verts, axis=0)
        print(
            name,
            len(mesh.verts),
            "vertices",
            len(mesh.faces),
            "faces",
            mesh.texture.shape[1::-1],
            "extent",
            np.round(extent, 3),
        )
    out = ASSETS / "textures"
    out.mkdir(exist_ok=True)
    for name in SURFACES:
        image = Image.open(roots["robosuite"] / "textures" / f"{name}.png").convert("RGB")
        image = image.resize((SURFACE_SIZE, SURFACE_SIZE), Image.Resampling.LANCZOS)
        image.save(out / f"{name}.png", optimize=True)
        print(name, image.size)


if __name__ == "__main__":
    if sys.argv[1] == "--panda":
        prepare_panda(sys.argv[2])
    else:
        main(*sys.argv[1:3])
