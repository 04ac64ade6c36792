"""Write eight meshes that are not built-in examples, to check settings on shapes nobody tuned them for.

    python benchmarks/make_test_meshes.py OUT_DIR
    python benchmarks/make_test_meshes.py OUT_DIR --sweep   # and the sweep of families: which preset the default takes
    python benchmarks/make_test_meshes.py OUT_DIR --boards  # and shelves of boards 0.05-4 voxels thick: their grids

``--sweep`` also writes ruins of every family (round and square plans, stepped and flat tops, walls 2 to 8 voxels
thick at 64, and uneven ones) as ``OUT_DIR/sweep/*.obj`` and prints, for them, the built-ins and the six meshes, the share of the
solid in thin parts (``auto.fit_default.thin_share``) and the preset ``fit`` takes without ``--preset`` on a CPU
with fast bf16 and on one without.

* ``rocks.stl``  — untextured (STL has no colour): a slab with a random field of boxes and
  squashed spheres on it, some merged (a closed mesh of several parts).
* ``tiles.obj``  — two materials, each with its own texture image: a tiled slab whose even
  tiles are red brick-like stripes and odd tiles blue checks, raised by different heights.
* ``dunes.ply``  — vertex colours only (no UVs): a slab whose top is a field of crossing
  sand ridges, darker in the troughs (a smooth, organic surface; no thin parts).
* ``ruin.obj``   — a ruined round tower (``sin3dm_lite.examples.ruin``): walls 2.5 voxels thick at a
  64-voxel training grid, a stepped broken top, a door and two windows (the paper's kind of demo shape).
* ``keep.obj``   — the same ruin with a square plan (``build_ruin(square=True)``): straight thin walls,
  the stepped top, a door and two windows (a second thin-walled shape, of another plan).
* ``tower.stl``  — geometry only, another round ruin whose walls go from 3 to 6 voxels thick and back twice
  around (``build_ruin(7, wall_voxels=(3, 6))``): the kind of real tower the default is judged on.
* ``plain_tower.stl`` — the same kind without windows, a door only (``build_ruin(11, wall_voxels=(3, 6),
  windows=False)``): plainer walls, where the default lands on the edge of the goals (docs/lab-notes.md).
* ``courtyard.obj`` — geometry only, a walled courtyard modelled as scenes often are: the ground and the four
  walls are open sheets of one quad each (no thickness), seven closed halls stand on the ground. The grid makes
  the sheets slabs 1/32 of its longest side thick (docs/fit-your-shape.md); before, it lost them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from sin3dm_lite.examples.ruin import build_ruin
from sin3dm_lite.formats.export import save_obj


def rocks(seed: int = 1) -> trimesh.Trimesh:
    rng = np.random.default_rng(seed)
    parts = [trimesh.creation.box(extents=(4.0, 0.3, 2.0))]
    for _ in range(28):
        x, z = rng.uniform(-1.8, 1.8), rng.uniform(-0.8, 0.8)
        if rng.random() < 0.5:
            e = rng.uniform(0.15, 0.45, 3)
            b = trimesh.creation.box(extents=e)
            b.apply_transform(trimesh.transformations.rotation_matrix(rng.uniform(0, np.pi), (0, 1, 0)))
            b.apply_translation((x, 0.15 + e[1] / 2, z))
        else:
            r = rng.uniform(0.12, 0.3)
            b = trimesh.creation.icosphere(subdivisions=2, radius=r)
            b.apply_scale((1.0, rng.uniform(0.5, 1.2), 1.0))
            b.apply_translation((x, 0.15, z))
        parts.append(b)
    return trimesh.util.concatenate(parts)


def _texture(kind: str, size: int = 256) -> Image.Image:
    u, v = np.meshgrid(np.arange(size), np.arange(size))
    if kind == "brick":
        rows = (v // 32) % 2
        mortar = (v % 32 < 3) | (((u + rows * 32) % 64) < 3)
        img = np.where(mortar[..., None], [200, 195, 185], [150, 60, 40]).astype(np.uint8)
    else:
        check = ((u // 32) + (v // 32)) % 2 == 0
        img = np.where(check[..., None], [40, 70, 160], [200, 210, 230]).astype(np.uint8)
    return Image.fromarray(img)


def tiles(out: Path, n: int = 6, seed: int = 3) -> Path:
    """An OBJ with two materials (brick / check), each with its own PNG and UVs per tile (heights drawn from ``seed``)."""
    lines_v, lines_vt, faces = [], [], {"brick": [], "check": []}
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    rng = np.random.default_rng(seed)
    for i in range(n):
        for j in range(n // 2):
            h = 0.2 + 0.25 * rng.random()
            tile = box.copy()
            tile.apply_scale((0.9, h, 0.9))
            tile.apply_translation((i - n / 2 + 0.5, h / 2, j - n / 4 + 0.5))
            base = len(lines_v)
            lines_v += [f"v {x:.5f} {y:.5f} {z:.5f}" for x, y, z in tile.vertices]
            vt0 = len(lines_vt)
            # planar UVs from x/z (top) and x/y (sides): good enough to show each texture
            for x, y, z in tile.vertices:
                lines_vt.append(f"vt {(x + z) * 0.5 % 1:.5f} {(y + z) * 0.5 % 1:.5f}")
            mat = "brick" if (i + j) % 2 == 0 else "check"
            for f in tile.faces:
                a, b, c = (base + k + 1 for k in f)
                ta, tb, tc = (vt0 + k + 1 for k in f)
                faces[mat].append(f"f {a}/{ta} {b}/{tb} {c}/{tc}")
    out.mkdir(parents=True, exist_ok=True)
    for mat in faces:
        _texture(mat).save(out / f"{mat}.png")
    (out / "tiles.mtl").write_text("".join(f"newmtl {m}\nKd 1 1 1\nmap_Kd {m}.png\n\n" for m in faces))
    body = ["mtllib tiles.mtl", *lines_v, *lines_vt]
    for mat, fl in faces.items():
        body += [f"usemtl {mat}", *fl]
    (out / "tiles.obj").write_text("\n".join(body) + "\n")
    return out / "tiles.obj"


def dunes(seed: int = 2, nx: int = 121, nz: int = 61) -> trimesh.Trimesh:
    """A closed heightfield slab 4 × 2 (x, z): ridges of a few random directions and wavelengths, coloured by height."""
    rng = np.random.default_rng(seed)
    x, z = np.meshgrid(np.linspace(-2, 2, nx), np.linspace(-1, 1, nz), indexing="ij")
    h = np.zeros_like(x)
    for _ in range(4):
        a = rng.uniform(0, np.pi)
        k = 2 * np.pi / rng.uniform(0.6, 1.6)
        t = (x * np.cos(a) + z * np.sin(a)) * k + rng.uniform(0, 2 * np.pi)
        h += rng.uniform(0.05, 0.12) * (np.abs(np.sin(t / 2)) * 2 - 1)  # sharp crests, round troughs
    h = 0.35 + h - h.min()
    top = np.stack([x, h, z], -1).reshape(-1, 3)
    bottom = np.stack([x, np.zeros_like(h), z], -1).reshape(-1, 3)
    v = np.concatenate([top, bottom])
    idx = np.arange(nx * nz).reshape(nx, nz)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = [np.stack([a, c, b], 1), np.stack([a, d, c], 1)]  # top, facing +y
    off = nx * nz
    faces += [np.stack([a, b, c], 1) + off, np.stack([a, c, d], 1) + off]  # bottom, facing -y
    for edge in (idx[:, 0], idx[-1, :], idx[::-1, -1], idx[0, ::-1]):  # the four sides, walked around the rim
        p, q = edge[:-1], edge[1:]
        faces += [np.stack([p, q, q + off], 1), np.stack([p, q + off, p + off], 1)]
    mesh = trimesh.Trimesh(v, np.concatenate(faces), process=True)
    if mesh.volume < 0:
        mesh.invert()
    t = (v[:, 1] - h.min()) / (h.max() - h.min() + 1e-9)
    t = np.where(v[:, 1] == 0, 0.0, t)
    sand, shade = np.array([222, 190, 130]), np.array([150, 105, 60])
    rgb = (shade + (sand - shade) * t[:, None]).astype(np.uint8)
    mesh.visual.vertex_colors = np.concatenate([rgb, np.full((len(v), 1), 255, np.uint8)], 1)[: len(mesh.vertices)]
    return mesh


def courtyard(seed: int = 5) -> trimesh.Trimesh:
    """A walled courtyard as scenes are often modelled: the ground and the enclosing walls are open sheets (one
    quad each, no thickness), the halls in it closed boxes standing on the ground (geometry only)."""
    rng = np.random.default_rng(seed)
    quads = [[(-2, 0, -2), (-2, 0, 2), (2, 0, 2), (2, 0, -2)]]  # the ground, facing up
    for a, b in (
        ((-1.6, -1.6), (1.6, -1.6)),
        ((1.6, -1.6), (1.6, 1.6)),
        ((1.6, 1.6), (-1.6, 1.6)),
        ((-1.6, 1.6), (-1.6, -1.6)),
    ):
        quads.append([(a[0], 0, a[1]), (b[0], 0, b[1]), (b[0], 0.35, b[1]), (a[0], 0.35, a[1])])  # a wall sheet
    v = np.array([p for q in quads for p in q], float)
    f = np.array(
        [(4 * i, 4 * i + 1, 4 * i + 2) for i in range(len(quads))]
        + [(4 * i, 4 * i + 2, 4 * i + 3) for i in range(len(quads))]
    )
    parts = [trimesh.Trimesh(v, f, process=False)]
    for _ in range(7):
        e = rng.uniform((0.3, 0.2, 0.3), (0.8, 0.6, 0.6))
        hall = trimesh.creation.box(extents=e)
        hall.apply_translation((rng.uniform(-1.2, 1.2), e[1] / 2, rng.uniform(-1.2, 1.2)))
        parts.append(hall)
    return trimesh.util.concatenate(parts)


def sweep(out: Path) -> None:
    """The family sweep: each shape's thin share and the default's choice on both kinds of CPU."""
    from sin3dm_lite.auto.fit_default import FINER, MOSTLY_THIN, thin_share
    from sin3dm_lite.examples import build_example, list_examples
    from sin3dm_lite.formats.load import load_mesh
    from sin3dm_lite.presets import get_preset

    (out / "sweep").mkdir(exist_ok=True)
    shapes = {name: (lambda n=name: build_example(n)) for name in list_examples()}
    shapes |= {
        f.name: (lambda f=f: load_mesh(f)) for f in sorted(out.iterdir()) if f.suffix in (".obj", ".stl", ".ply")
    }
    for plan in ("round", "square"):
        for top in ("stepped", "flat"):
            for wall in (2, 3, 4, 5, 6, 8, (2, 4), (3, 6), (4, 8)):
                mesh = build_ruin(3, wall_voxels=wall, square=plan == "square", flat=top == "flat")
                walls = "-".join(map(str, np.ravel(wall)))
                path = out / "sweep" / f"ruin_{plan}_{top}_{walls}.obj"
                save_obj(mesh, path)
                shapes[f"ruin, {plan}, {top} top, walls {walls.replace('-', ' to ')} voxels"] = lambda p=path: (
                    load_mesh(p)
                )
    print("| shape | thin share (parts under 7 voxels at 64) | fast bf16 | no fast bf16 |\n|---|---|---|---|")
    for name, make in shapes.items():
        share = thin_share(make(), get_preset("small"))
        pick = {m: FINER[m] if share > MOSTLY_THIN else m for m in ("small", "quick")}
        print(f"| {name} | {share:.2f} | `{pick['small']}` | `{pick['quick']}` |", flush=True)


def shelf(board: float) -> trimesh.Trimesh:
    """A shelf of closed boards ``board`` thick (the mesh's units; its longest side is 2): four shelves, three
    uprights, each board a part of its own, as a storage shelf is modelled."""
    boards = [
        trimesh.creation.box(extents=(2.0, board, 1.0)).apply_translation((0, y, 0)) for y in (-0.6, -0.2, 0.2, 0.6)
    ]
    for x in (-1.0 + board / 2, 0.0, 1.0 - board / 2):
        boards.append(trimesh.creation.box(extents=(board, 1.2 + board, 1.0)).apply_translation((x, 0, 0)))
    return trimesh.util.concatenate(boards)


def boards(out: Path) -> None:
    """The thin-board sweep: shelves of boards 0.05 to 4 voxels thick at 64; per grid, whether the boards became
    slabs and how many voxels a shelf holds across (one column through its middle)."""
    import warnings

    from sin3dm_lite.data.grid import mesh_to_grid
    from sin3dm_lite.errors import Sin3DMInputError
    from sin3dm_lite.formats.load import load_mesh

    (out / "boards").mkdir(exist_ok=True)
    print("| board, voxels at 64 | " + " | ".join(f"at {r}: slab? voxels across" for r in (64, 96)) + " |")
    print("|---|---|---|")
    for voxels in (0.05, 0.25, 0.5, 0.75, 1.0, 1.25, 1.4, 1.6, 2.0, 2.5, 3.0, 4.0):
        path = out / "boards" / f"shelf_{voxels:g}.stl"
        shelf(voxels * 2.0 / 64).export(path)
        cells = []
        for res in (64, 96):
            with warnings.catch_warnings(record=True) as said:
                warnings.simplefilter("always")
                try:
                    g = mesh_to_grid(load_mesh(path), res, n_surface_points=0, progress=False, margin_voxels=3.25)
                except Sin3DMInputError:  # the grid's error is the answer: nothing inside
                    cells.append("no inside")
                    continue
            slab = any("thinner than" in str(w.message) for w in said)
            at = g.normalization.to_normalized(np.array([[0.5, 0.2, 0.0]]))[0]
            i, k = (int(np.floor((at[a] - g.aabb[a]) / g.voxel_size)) for a in (0, 2))
            y = np.abs(g.axis_coords(1) - at[1]) < 4 * g.voxel_size
            cells.append(f"{'slab' if slab else '-'}, {int((g.sdf[i, y, k] < 0).sum())}")
        print(f"| {voxels:g} | " + " | ".join(cells) + " |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", nargs="?", default="runs/meshes", help="the folder to write to (default runs/meshes)")
    ap.add_argument("--sweep", action="store_true", help="also the sweep of families and the preset each takes")
    ap.add_argument("--boards", action="store_true", help="also shelves of boards 0.05-4 voxels thick")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rocks().export(out / "rocks.stl")
    dunes().export(out / "dunes.ply")
    save_obj(build_ruin(0), out / "ruin.obj")
    save_obj(build_ruin(0, square=True), out / "keep.obj")
    tower = build_ruin(7, wall_voxels=(3, 6))
    trimesh.Trimesh(tower.vertices, tower.faces, process=False).export(out / "tower.stl")
    plain = build_ruin(11, wall_voxels=(3, 6), windows=False)
    trimesh.Trimesh(plain.vertices, plain.faces, process=False).export(out / "plain_tower.stl")
    courtyard().export(out / "courtyard.obj")
    made = (
        f"{out / 'rocks.stl'}, {tiles(out)}, {out / 'dunes.ply'}, ruin.obj, keep.obj, tower.stl, plain_tower.stl and "
        "courtyard.obj"
    )
    print(f"wrote {made} to {out}")
    if args.sweep:
        sweep(out)
    if args.boards:
        boards(out)


if __name__ == "__main__":
    main()
