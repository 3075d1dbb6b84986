"""The floor of the largest vertex-to-cloud distance on a capture: what any sheet that fills
the mask must score, beside what a reconstruction scores.

    python benchmarks/sft_vertex_floor.py --data PATH [--result DIR] [--outline 2]

The acceptance's "no vertex farther than 20 mm from the cloud" is measured against a Kinect
cloud that does not reach the sheet's edges everywhere. This measures, per frame, how far a
surface that covers the cloth's mask (the mask's largest connected part; R1's masks also
hold two small blobs) must at least be from the cloud: each mask pixel farther than two
cloud-point spacings (in the image) from every projected cloud point is uncovered; a sheet
point X seen at that pixel is at least |X| sin α from any cloud point, α the angle between its
ray and the nearest covered pixel's ray, with |X| taken at that cloud point's depth. The
largest of these over the mask, less its outermost `--outline` pixels (the mask's own
uncertainty; the whole mask's figure is printed beside it), is the floor: a lower bound of
the largest distance of any mask-filling surface (the sheet can hide further along the rays,
so it is not the best achievable score, which can only be higher). With `--result` (an
`ndf-sft` output folder) the reconstruction's
largest vertex-to-cloud distance per frame is printed beside it.

Camera: the capture's camera.json (fx, fy, cx, cy); clouds ground_truth/*.npy in camera
coordinates [m]; masks masks/*.png. Prints a markdown table; figures: benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from taichi_ndf.io import read_mesh


def sheet_mask(path: Path) -> np.ndarray:
    """The mask's largest 8-connected part, bool (H, W)."""
    mask = (cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) > 127).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if count < 2:
        return mask.astype(bool)
    return labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))


def rays(pixels: np.ndarray, camera: dict) -> np.ndarray:
    """Unit viewing rays (N, 3) of pixels (N, 2) (OpenCV pinhole, pixel centres at integers)."""
    r = np.column_stack([(pixels[:, 0] - camera["cx"]) / camera["fx"],
                         (pixels[:, 1] - camera["cy"]) / camera["fy"], np.ones(len(pixels))])
    return r / np.linalg.norm(r, axis=1, keepdims=True)


def frame_floor(cloud: np.ndarray, mask: np.ndarray, camera: dict, outline: int) -> dict:
    """The floor (module docstring) of one frame [m], and the uncovered share of the mask."""
    pixels = np.column_stack([camera["fx"] * cloud[:, 0] / cloud[:, 2] + camera["cx"],
                              camera["fy"] * cloud[:, 1] / cloud[:, 2] + camera["cy"]])
    tree = cKDTree(pixels)
    spacing = float(np.median(tree.query(pixels, k=2)[0][:, 1]))
    if outline:
        kernel = np.ones((2 * outline + 1, 2 * outline + 1), np.uint8)
        mask = cv2.erode(mask.astype(np.uint8), kernel).astype(bool)
    ys, xs = np.nonzero(mask)
    seen = np.column_stack([xs, ys]).astype(np.float64)
    gap, nearest = tree.query(seen)
    uncovered = gap > 2 * spacing
    cos = np.clip(np.sum(rays(seen, camera) * rays(pixels[nearest], camera), axis=1), -1, 1)
    floor = np.linalg.norm(cloud[nearest], axis=1) * np.sqrt(1 - cos**2)
    floor = np.where(uncovered, floor, 0.0)
    return {"floor_m": float(floor.max(initial=0.0)), "uncovered": float(uncovered.mean()),
            "spacing_px": spacing}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", type=Path, required=True, help="the capture folder")
    p.add_argument("--result", type=Path, help="an ndf-sft output folder (meshes/*.obj)")
    p.add_argument("--outline", type=int, default=2, help="mask pixels dropped at its outline")
    args = p.parse_args()
    camera = json.loads((args.data / "camera.json").read_text())
    clouds = sorted((args.data / "ground_truth").glob("*.npy"))
    masks = sorted((args.data / "masks").glob("*.png"))
    meshes = sorted((args.result / "meshes").glob("*.obj")) if args.result else []
    print(f"| frame | floor [mm], mask less {args.outline} px | floor [mm], whole mask | "
          "uncovered mask | reconstruction's largest distance [mm] |")
    print("|---|---|---|---|---|")
    floors, reached = [], []
    for i, (cloud_path, mask_path) in enumerate(zip(clouds, masks, strict=False)):
        cloud = np.load(cloud_path).astype(np.float64)
        mask = sheet_mask(mask_path)
        row = frame_floor(cloud, mask, camera, args.outline)
        whole = frame_floor(cloud, mask, camera, 0)["floor_m"] if args.outline else row["floor_m"]
        floors.append(row["floor_m"])
        largest = ""
        if i < len(meshes):
            vertices = np.asarray(read_mesh(meshes[i]).vertices, dtype=np.float64)
            reached.append(float(cKDTree(cloud).query(vertices)[0].max()))
            largest = f"{1e3 * reached[-1]:.1f}"
        print(f"| {i} | {1e3 * row['floor_m']:.1f} | {1e3 * whole:.1f} | "
              f"{100 * row['uncovered']:.1f} % | "
              f"{largest} |", flush=True)
    worst = int(np.argmax(floors))
    print(f"\nfloor: largest {1e3 * floors[worst]:.1f} mm (frame {worst}), median "
          f"{1e3 * float(np.median(floors)):.1f} mm over {len(floors)} frames")
    if reached:
        excess = np.array(reached) - np.array(floors[:len(reached)])
        print(f"reconstruction: largest {1e3 * max(reached):.1f} mm (frame "
              f"{int(np.argmax(reached))}); above the floor by at most {1e3 * excess.max():.1f}"
              f" mm (frame {int(np.argmax(excess))})")


if __name__ == "__main__":
    main()
