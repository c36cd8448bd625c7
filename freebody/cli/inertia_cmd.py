"""``freebody inertia``: mass, COM and inertia tensor of a mesh file or a primitive shape.

Exact (closed form for a shape, polyhedral integration for a mesh) or approximated by particles or
voxels; ``--compare`` tabulates and plots how both approximations converge to the exact result.
"""
from __future__ import annotations

ORDER = 40

from ..errors import InputError
from .argtypes import integer, nonnegative_int as _seed, quantity as _positive, writable_folder

_resolution = integer(1, 1024)

DEFAULT_OUT = "reports/latest"
DEFAULT_RESOLUTION = 32  # --method particles|voxels: cells along the longest bounding-box side
DEFAULT_COMPARE_MAX = 64  # --compare: the finest resolution (64^3 cells at most: about a second)
SCHEMA_VERSION = 1  # of inertia_<name>.json


def add_parser(sub) -> None:
    from ..reference_impl.massprops import SIZE_DOC

    shapes = "; ".join(f"{k} {v}" for k, v in SIZE_DOC.items())
    p = sub.add_parser(
        "inertia", help="mass, COM and inertia tensor of a mesh (OBJ/STL) or a primitive shape",
        description="Print mass, COM, the inertia tensor I_b about the COM and its principal moments "
                    "and axes, for a closed triangle mesh (OBJ or STL; exact polyhedral integration) "
                    "or a primitive shape (closed form), or approximated by particles or voxels.")
    p.add_argument("target", metavar="PATH|SHAPE",
                   help=f"a mesh file (.obj, .stl; units m) or a shape with --size (m): {shapes}")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--density", type=_positive, metavar="RHO", help="uniform density, kg/m^3")
    g.add_argument("--mass", type=_positive, metavar="M", help="total mass, kg (uniform density)")
    p.add_argument("--size", type=_positive, nargs="+", metavar="S", help="the shape's size, m")
    p.add_argument("--method", choices=["exact", "particles", "voxels"], default="exact",
                   help="exact (default), particles (a seeded point-mass sample) or voxels (cells)")
    p.add_argument("--resolution", type=_resolution, metavar="N",
                   help=f"cells along the longest bounding-box side (default {DEFAULT_RESOLUTION}; "
                        f"with --compare the finest resolution, default {DEFAULT_COMPARE_MAX})")
    p.add_argument("--seed", type=_seed, default=0, help="seed of the particle sample (default 0)")
    p.add_argument("--compare", action="store_true",
                   help="table and log-log plot of the particle and voxel errors against the exact "
                        "result as the resolution grows")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"where --compare writes inertia_<name>.png and .json (default {DEFAULT_OUT})")
    p.add_argument("--force-large", action="store_true",
                   help="start even when the grid's estimated memory exceeds the memory available")


def run(args) -> int:
    from ..tools.inertia import compare, compare_table, load_target, report_approx, report_exact, write_compare

    target = load_target(args.target, args.size, density=args.density, mass=args.mass)
    if args.compare and args.method != "exact":
        raise InputError("--compare: compares every method with the exact result; drop --method")
    if args.compare or args.method != "exact":
        from ..run.budget import check_inertia, grid_cells

        n = args.resolution or (DEFAULT_COMPARE_MAX if args.compare else DEFAULT_RESOLUTION)
        # --compare ends with particles at the finest resolution: the larger of the two methods
        check_inertia(grid_cells(target.solid.lo, target.solid.hi, n),
                      "particles" if args.compare else args.method, target.kind == "mesh",
                      force=args.force_large)
    if args.compare:
        out_dir = writable_folder(args.out, "--out",  # before the work, so that none is lost
                                  files=(f"inertia_{target.name}.png", f"inertia_{target.name}.json"))
        rows = compare(target, args.resolution or DEFAULT_COMPARE_MAX, seed=args.seed)
        print(report_exact(target))
        print()
        print(compare_table(rows))
        png, js = write_compare(target, rows, out_dir, SCHEMA_VERSION)
        print(f"\nplot: {png}\ntable: {js}")
        return 0
    if args.method == "exact":
        print(report_exact(target))
        return 0
    print(report_approx(target, args.method, args.resolution or DEFAULT_RESOLUTION, args.seed))
    return 0
