"""Time mesh → grid (issue: 128³ ≤ 5 s and 256³ ≤ 20 s for a 77k-face textured mesh on 2 cores).

python benchmarks/bench_grid.py [--resolutions 128 256] [--faces 77000]
"""

import argparse
import time
import tracemalloc

import numpy as np
import trimesh

from sin3dm_lite.data.grid import mesh_to_grid
from sin3dm_lite.data.mesh import Material, TexturedMesh


def bumpy_textured_sphere(target_faces: int) -> TexturedMesh:
    """An icosphere with bumps, cut to ~target_faces (open; all 81,920 = closed), with a striped UV texture."""
    m = trimesh.creation.icosphere(subdivisions=6)  # 81,920 faces
    m = trimesh.Trimesh(m.vertices, m.faces[:target_faces], process=False)  # an open mesh, as assets often are
    v = np.asarray(m.vertices)
    v = v * (1 + 0.08 * np.sin(7 * v[:, :1]) * np.cos(5 * v[:, 1:2]))
    f = np.asarray(m.faces, np.int64)
    uv = np.stack([np.arctan2(v[:, 1], v[:, 0]) / (2 * np.pi) + 0.5, v[:, 2] / 2 + 0.5], 1)
    yy, xx = np.mgrid[0:512, 0:512] / 512
    tex = np.stack([0.5 + 0.5 * np.sin(40 * yy), 0.5 + 0.5 * np.sin(25 * xx), 0.5 + 0 * xx], -1).astype(np.float32)
    return TexturedMesh(
        v,
        f,
        np.zeros(len(f), np.int64),
        [Material(base_color=np.ones(4, np.float32), image=tex)],
        face_uvs=uv[f].astype(np.float32),
        name="bumpy_sphere",
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--resolutions", type=int, nargs="+", default=[128, 256])
    ap.add_argument("--faces", type=int, default=77_000, help="faces kept of 81,920 (81920: a closed mesh)")
    ap.add_argument("--points", type=int, default=300_000, help="near-surface training samples (small preset: 300k)")
    a = ap.parse_args()
    mesh = bumpy_textured_sphere(a.faces)
    print(f"mesh: {len(mesh.faces):,} faces, textured, {'closed' if len(mesh.faces) == 81_920 else 'open'}")
    mesh_to_grid(mesh, 32, n_surface_points=0, progress=False)  # warm-up (imports, first-call costs)
    for res in a.resolutions:
        for points in (0, a.points):
            tracemalloc.start()
            t = time.perf_counter()
            g = mesh_to_grid(mesh, res, n_surface_points=points, progress=False)
            dt = time.perf_counter() - t
            peak = tracemalloc.get_traced_memory()[1] / 2**20
            tracemalloc.stop()
            what = "grid only" if points == 0 else f"+ {points:,} training points"
            print(f"grid {res:4d}: {g.shape} in {dt:6.2f} s  {what:28s} (peak numpy memory {peak:,.0f} MiB)")


if __name__ == "__main__":
    main()
