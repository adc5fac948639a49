"""A small end-to-end look at the ground floor: the real sky through paper 000's camera at a random attitude."""

import numpy as np

from startracker.catalog import load_catalog
from startracker.optics import camera_preset
from startracker.rotations import quat_random, quat_to_matrix


def main(seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    cat = load_catalog(mag_limit=6.0, epoch=2025.0)
    cam = camera_preset("paper000")
    q_cam_to_icrs = quat_random(rng)
    v_cam = cat.vectors @ quat_to_matrix(q_cam_to_icrs)  # R^T v for each row
    xy, inside = cam.project(v_cam)
    idx = np.flatnonzero(inside)
    print(f"catalog: {len(cat)} stars with V <= 6.0 at epoch {cat.epoch}")
    print(f"camera {cam.name}: {cam.fov_deg[0]:.1f} x {cam.fov_deg[1]:.1f} deg, {cam.resolution[0]}x{cam.resolution[1]} px")
    print(f"attitude q_cam_to_icrs = {np.round(q_cam_to_icrs, 4)}: {len(idx)} stars on the detector")
    print(f"{'HIP':>7} {'V':>6} {'col px':>9} {'row px':>9}")
    for i in idx[np.argsort(cat.vmag[idx])][:10]:
        print(f"{cat.hip[i]:7d} {cat.vmag[i]:6.2f} {xy[i, 0]:9.2f} {xy[i, 1]:9.2f}")


if __name__ == "__main__":
    main()
