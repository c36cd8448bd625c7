"""Generate the bundled example meshes under cases/meshes/ (closed, outward-wound OBJ files).

    python scripts/make_meshes.py [--out cases/meshes] [--check]

Each solid is a union of axis-aligned boxes minus others, meshed exactly: the box faces define a
rectilinear grid, a grid cell is solid when its centre lies in an added box and in no removed one,
and every grid face between a solid and an empty cell becomes two triangles wound
counter-clockwise seen from outside.  The result is deterministic (the same bytes every run);
``--check`` exits 1 if the committed files differ from what this script writes.

Shapes (m, in each file's own frame, which is *not* centred on the COM):

* ``t_handle``: a T-handle: a 0.12 m bar of 0.02 m square section along x, and a 0.08 m shaft of
  0.016 m square section hanging from its middle along -z.  Its intermediate principal axis is
  body z (the shaft): spun about it, it flips (the Dzhanibekov effect).
* ``wing_nut``: a Dzhanibekov-like wing nut: a square hub with a square bore along z and two
  stepped wings along +-x, thin in y.
* ``l_shape``: a non-convex L-shaped plate, 0.10 x 0.08 m, 0.02 m thick, its corner at the origin.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a checkout without installing

from freebody.input.meshfile import format_obj  # noqa: E402
from freebody.reference_impl.mesh import TriangleMesh, mass_properties, validate  # noqa: E402

Box = tuple[tuple[float, float, float], tuple[float, float, float]]  # (lo, hi), m

SHAPES: dict[str, tuple[str, list[Box], list[Box]]] = {
    "t_handle": (
        "T-handle: bar 0.12 x 0.02 x 0.02 m along x, shaft 0.016 x 0.016 x 0.08 m along -z",
        [((-0.06, -0.01, 0.0), (0.06, 0.01, 0.02)),
         ((-0.008, -0.008, -0.08), (0.008, 0.008, 0.0))],
        [],
    ),
    "wing_nut": (
        "Dzhanibekov-like wing nut: hub 0.02 x 0.02 x 0.016 m with a 0.008 m square bore along z, "
        "two stepped wings 0.004 m thick along +-x",
        [((-0.01, -0.01, -0.008), (0.01, 0.01, 0.008)),
         ((0.01, -0.002, -0.008), (0.025, 0.002, 0.010)),
         ((0.025, -0.002, -0.004), (0.035, 0.002, 0.016)),
         ((-0.025, -0.002, -0.008), (-0.01, 0.002, 0.010)),
         ((-0.035, -0.002, -0.004), (-0.025, 0.002, 0.016))],
        [((-0.004, -0.004, -0.008), (0.004, 0.004, 0.008))],
    ),
    "l_shape": (
        "non-convex L-shaped plate: legs 0.10 x 0.03 m and 0.03 x 0.08 m, 0.02 m thick",
        [((0.0, 0.0, 0.0), (0.10, 0.03, 0.02)),
         ((0.0, 0.0, 0.0), (0.03, 0.08, 0.02))],
        [],
    ),
}


def _in_boxes(p: np.ndarray, boxes: list[Box]) -> np.ndarray:
    out = np.zeros(len(p), bool)
    for lo, hi in boxes:
        out |= np.all((p > np.array(lo)) & (p < np.array(hi)), axis=1)
    return out


def box_union_mesh(add: list[Box], remove: list[Box]) -> TriangleMesh:
    """The boundary of (union of ``add``) minus (union of ``remove``) as a closed triangle mesh."""
    grid = [np.unique([b[s][a] for b in add + remove for s in (0, 1)]) for a in range(3)]
    n = [len(g) - 1 for g in grid]
    centres = [0.5 * (g[1:] + g[:-1]) for g in grid]
    C = np.stack(np.meshgrid(*centres, indexing="ij"), axis=-1).reshape(-1, 3)
    solid = (_in_boxes(C, add) & ~_in_boxes(C, remove)).reshape(n)
    padded = np.pad(solid, 1)  # empty cells all round
    point_id = lambda i, j, k: (i * len(grid[1]) + j) * len(grid[2]) + k  # noqa: E731
    tris = []
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        # each grid plane k along axis a: compare the cells on its two sides
        for k in range(len(grid[a])):
            sl_lo = [slice(1, -1)] * 3
            sl_hi = [slice(1, -1)] * 3
            sl_lo[a], sl_hi[a] = k, k + 1  # padded index k is cell k-1
            before, after = padded[tuple(sl_lo)], padded[tuple(sl_hi)]
            for (i, j) in zip(*np.nonzero(before != after)):
                ij = {b: (i, i + 1), c: (j, j + 1)} if b < c else {b: (j, j + 1), c: (i, i + 1)}
                corners = []
                for db, dc in ((0, 0), (1, 0), (1, 1), (0, 1)):  # counter-clockwise about +a
                    idx = [0, 0, 0]
                    idx[a], idx[b], idx[c] = k, ij[b][db], ij[c][dc]
                    corners.append(point_id(*idx))
                if not before[i, j]:  # solid above the plane: the outward normal is -a
                    corners.reverse()
                p, q, r, s = corners
                tris += [(p, q, r), (p, r, s)]
    G = np.stack(np.meshgrid(*grid, indexing="ij"), axis=-1).reshape(-1, 3)
    t = np.array(tris)
    used, inverse = np.unique(t, return_inverse=True)
    return TriangleMesh(G[used], inverse.reshape(t.shape))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "cases" / "meshes"), help="output directory")
    ap.add_argument("--check", action="store_true", help="compare with the files instead of writing")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stale = []
    for name, (what, add, remove) in SHAPES.items():
        mesh = box_union_mesh(add, remove)
        validate(mesh)
        props = mass_properties(mesh, 1000.0)
        text = format_obj(mesh, f"{name}: {what}\ngenerated by scripts/make_meshes.py; units m; "
                                f"{len(mesh.triangles)} triangles, volume {props.volume:.6g} m^3")
        path = out / f"{name}.obj"
        if args.check:
            if not path.is_file() or path.read_text() != text:
                stale.append(str(path))
            continue
        path.write_text(text)
        moments = np.linalg.eigvalsh(props.inertia)
        print(f"{path}: {len(mesh.triangles)} triangles, volume {props.volume:.6g} m^3, "
              f"COM {np.round(props.com, 6).tolist()} m, principal moments at 1000 kg/m^3 "
              f"{moments.tolist()} kg m^2")
    if stale:
        print("stale (re-run scripts/make_meshes.py): " + ", ".join(stale), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
