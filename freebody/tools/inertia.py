"""The work behind ``freebody inertia``: a body from a mesh file or a shape, its exact mass
properties, the particle and voxel approximations, and their convergence table and plot.

Errors of an approximation against the exact result:

* mass: |m - m_exact| / m_exact (zero by construction when a total mass is given);
* COM: |c - c_exact| in m, and divided by the bounding box's diagonal for the plot;
* I_b: ||I - I_exact||_F / ||I_exact||_F, both about their own COM, in the body axes.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import tolerances as tol
from ..errors import InputError, printable
from ..input.casefile import validate_inertia, validate_mass, validate_volume
from ..reference_impl import approx, massprops, primitives
from ..reference_impl.mesh import MeshError, TriangleMesh, mass_properties


@dataclass(frozen=True)
class Target:
    """A uniform solid and its exact mass properties.

    name : str, for file names (the mesh's stem or the shape).  label : str, for humans.
    kind : "mesh" or "shape".  shape, size : the primitive (kind "shape"), size in m.
    mesh : TriangleMesh (kind "mesh"), m.  density : float, kg/m^3.  volume : float, m^3.
    mass : float, kg.  com : ndarray (3,), m, in the mesh's (or shape's) frame.
    inertia : ndarray (3, 3), kg m^2, about the COM, body axes.  solid : approx.Solid to sample.
    given_mass : bool, the user gave a mass (approximations then share it among their cells).
    """

    name: str
    label: str
    kind: str
    shape: str | None
    size: np.ndarray | None
    mesh: TriangleMesh | None
    density: float
    volume: float
    mass: float
    com: np.ndarray
    inertia: np.ndarray
    solid: approx.Solid
    given_mass: bool

    @property
    def diagonal(self) -> float:
        """The bounding box's diagonal, m."""
        return float(np.linalg.norm(self.solid.hi - self.solid.lo))


def load_target(target: str, size, *, density: float | None = None, mass: float | None = None) -> Target:
    """A mesh file (.obj/.stl) or a shape name with ``size``; exactly one of density and mass.

    Raises :class:`InputError` (one line naming the file or option) for bad input.
    """
    from ..input.meshfile import body_from_mesh

    path = Path(target)
    if target in massprops.SHAPES and not path.exists():
        n = massprops.SHAPES[target]
        if size is None:
            raise InputError(f"--size: missing; a {target} needs {n} number(s): {massprops.SIZE_DOC[target]} (m)")
        if len(size) != n:
            raise InputError(f"--size: a {target} needs {n} number(s) ({massprops.SIZE_DOC[target]}, m), "
                             f"got {len(size)}")
        s = np.array(size, dtype=float)
        vol = massprops.volume(target, s)
        validate_volume(vol, lambda why: _fail("--size", f"a {target} of this size: {why}"))
        rho = density if density is not None else mass / vol
        m = float(mass) if mass is not None else rho * vol
        _check_exact(m, rho, massprops.inertia(target, s, m), "--size", "--mass" if mass is not None else "--density")
        label = f"{target} size {s.tolist()} m ({massprops.SIZE_DOC[target]}); closed form"
        return Target(target, label, "shape", target, s, None, float(rho), vol, m, np.zeros(3),
                      massprops.inertia(target, s, m), approx.solid_from_shape(target, s), mass is not None)
    if os.path.isdir(path):
        raise InputError(f"{printable(target)}: is a folder, not a mesh file (.obj, .stl) or a shape (shapes: "
                         f"{', '.join(massprops.SHAPES)})")
    if not os.path.exists(path):  # something that is not a regular file: reading it says what it is
        raise InputError(f"{printable(target)}: no such file, and not a shape (shapes: "
                         f"{', '.join(massprops.SHAPES)})")
    if size is not None:
        raise InputError("--size: only with a shape; a mesh's size is in its coordinates (m)")
    try:
        mesh, props = body_from_mesh(path, density=density, mass=mass)
    except MeshError as e:
        raise InputError(f"{printable(target)}: {e}") from None
    validate_volume(props.volume, lambda why: _fail(printable(target), why))
    _check_exact(props.mass, props.mass / props.volume, props.inertia, printable(target),
                 "--mass" if mass is not None else "--density")
    label = (f"{target}: closed triangle mesh, {len(mesh.triangles)} triangles, "
             f"{len(np.unique(mesh.triangles))} vertices; exact polyhedral integration")
    return Target(path.stem, label, "mesh", None, None, mesh, props.mass / props.volume, props.volume,
                  props.mass, props.com, props.inertia, approx.solid_from_mesh(mesh), mass is not None)


def _fail(where: str, why: str):
    raise InputError(f"{where}: {why}")


def _check_exact(mass: float, density: float, I: np.ndarray, size_option: str, given_option: str) -> None:
    """InputError unless the exact mass (kg), density (kg/m^3) and inertia are numbers float64 can
    compute with (from INPUT_POSITIVE_MIN to INPUT_MAGNITUDE_MAX of freebody.tolerances)."""
    validate_mass(mass, lambda why: _fail(given_option, f"with this size, the {why}"))
    if not (tol.INPUT_POSITIVE_MIN <= density <= tol.INPUT_MAGNITUDE_MAX):
        _fail(given_option, f"with this size, the density {density:.6g} kg/m^3 is not from "
                            f"{tol.INPUT_POSITIVE_MIN:g} to {tol.INPUT_MAGNITUDE_MAX:g}: too large or too "
                            "small to compute with in float64")
    validate_inertia(I, lambda why: _fail(size_option, f"the inertia tensor: {why}"))


# --- text ---------------------------------------------------------------------------------------

def _vec(a, scale: float | None = None) -> str:
    a = np.asarray(a, dtype=float)
    cut = tol.INERTIA_DISPLAY_ZERO_RTOL * (np.max(np.abs(a)) if scale is None else scale)
    return "[" + ", ".join(f"{(0.0 if abs(x) <= cut else x): .10g}" for x in a) + "]"


def _mat(M, indent: str) -> str:
    scale = float(np.max(np.abs(M)))
    return "\n".join(indent + _vec(row, scale) for row in M)


def _properties_text(volume, mass, density, com, I, frame: str, size: float) -> str:
    moments, axes = massprops.principal(I)
    return "\n".join([
        f"density            {density:.10g} kg/m^3",
        f"volume             {volume:.10g} m^3",
        f"mass               {mass:.10g} kg",
        f"COM                {_vec(com, size)} m, {frame}",
        "I_b                kg m^2, about the COM, body axes (= the frame's axes):",
        _mat(I, "                   "),
        f"principal moments  {_vec(moments)} kg m^2, ascending",
        "principal axes     columns, body frame (I_b = A diag(moments) A^T):",
        _mat(axes, "                   "),
    ])


def _frame(t: Target) -> str:
    if t.kind == "mesh":
        return "in the mesh's frame (a case's body origin)"
    return "the shape's origin by construction"


def report_exact(t: Target) -> str:
    """The exact mass properties as text."""
    return t.label + "\n" + _properties_text(t.volume, t.mass, t.density, t.com, t.inertia, _frame(t),
                                              t.diagonal)


def errors(t: Target, mass: float, com: np.ndarray, I: np.ndarray) -> dict:
    """Errors of (mass kg, COM (3,) m, I (3, 3) kg m^2) against the exact result (see module doc)."""
    com_err = float(np.linalg.norm(np.asarray(com) - t.com))
    return {"mass_rel": abs(mass - t.mass) / t.mass, "com_m": com_err, "com_rel": com_err / t.diagonal,
            "inertia_rel": float(np.linalg.norm(I - t.inertia) / np.linalg.norm(t.inertia))}


def _approximate(t: Target, method: str, n: int, seed: int) -> approx.ApproxProperties:
    kw = {"mass": t.mass} if t.given_mass else {"density": t.density}
    if method == "particles":
        kw["seed"] = seed
    return approx.METHODS[method](t.solid, n, **kw)


def report_approx(t: Target, method: str, n: int, seed: int) -> str:
    """One approximation's mass properties and its errors against the exact result, as text."""
    r = _approximate(t, method, n, seed)
    head = (f"{t.label.split(';')[0]}; {method}, resolution {n}: {r.n_inside} of {r.n_cells} cells "
            f"of {_vec(r.cell)} m inside" + (f", seed {seed}" if method == "particles" else ""))
    if r.n_inside == 0:
        raise InputError(f"--resolution: {n} is too coarse: no {method} sample falls inside the body")
    e = errors(t, r.mass, r.com, r.inertia)
    return "\n".join([
        head,
        _properties_text(r.volume, r.mass, r.mass / r.volume, r.com, r.inertia, _frame(t), t.diagonal),
        f"error vs exact     mass {e['mass_rel']:.3e} (relative), COM {e['com_m']:.3e} m, "
        f"I_b {e['inertia_rel']:.3e} (relative Frobenius norm)",
    ])


# --- convergence --------------------------------------------------------------------------------

def resolutions(finest: int) -> list[int]:
    """2, 3, 4, 6, 8, 11, 16, ... (about sqrt(2) apart) up to and including ``finest``."""
    out = sorted({round(2 ** (k / 2)) for k in range(2, 2 * int(math.log2(max(finest, 2))) + 2)})
    return [n for n in out if n < finest] + [finest]


def compare(t: Target, finest: int, seed: int = approx.DEFAULT_SEED) -> list[dict]:
    """Rows {method, resolution, samples, cells, mass, errors...} for particles and voxels at each
    of :func:`resolutions` (and, for a shape, its inscribed polyhedron with N segments around)."""
    rows = []
    for method in ("particles", "voxels"):
        for n in resolutions(finest):
            r = _approximate(t, method, n, seed)
            row = {"method": method, "resolution": n, "cells": r.n_cells, "samples": r.n_inside,
                   "mass": r.mass}
            if r.n_inside:
                row.update(errors(t, r.mass, r.com, r.inertia))
            else:
                row.update({"mass_rel": math.nan, "com_m": math.nan, "com_rel": math.nan,
                            "inertia_rel": math.nan})
            rows.append(row)
    if t.kind == "shape" and t.shape != "box":  # a box's polyhedron is the box: always exact
        for n in resolutions(finest):
            if n < 3:
                continue
            poly = primitives.tessellate(t.shape, t.size, n)
            p = mass_properties(poly, t.density)
            if t.given_mass:
                p = mass_properties(poly, t.mass / p.volume)
            rows.append({"method": "polyhedron", "resolution": n, "cells": len(poly.triangles),
                         "samples": len(poly.triangles), "mass": p.mass,
                         **errors(t, p.mass, p.com, p.inertia)})
    return rows


def compare_table(rows: list[dict]) -> str:
    """The convergence rows as a fixed-width text table."""
    head = (f"{'method':<10}  {'N':>4}  {'cells':>8}  {'inside':>8}  {'mass err':>9}  "
            f"{'COM err m':>9}  {'I_b err':>9}")
    lines = [head, "-" * len(head)]
    for r in rows:
        if r["samples"] == 0:
            lines.append(f"{r['method']:<10}  {r['resolution']:>4}  {r['cells']:>8}  {0:>8}  "
                         "no sample inside")
            continue
        lines.append(f"{r['method']:<10}  {r['resolution']:>4}  {r['cells']:>8}  {r['samples']:>8}  "
                     f"{r['mass_rel']:>9.2e}  {r['com_m']:>9.2e}  {r['inertia_rel']:>9.2e}")
    lines.append("N: cells along the longest bounding-box side (polyhedron: segments around the axis; "
                 "cells = inside = triangles).")
    lines.append("errors: mass and I_b relative (I_b: Frobenius norm), COM in m; all against the exact result.")
    return "\n".join(lines)


def write_compare(t: Target, rows: list[dict], out_dir: Path, schema_version: int) -> tuple[Path, Path]:
    """Write ``inertia_<name>.png`` (log-log errors vs N) and ``inertia_<name>.json``; their paths."""
    from ..results.document import document_header
    from ..results.io import write_json_atomic

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    png = out_dir / f"inertia_{t.name}.png"
    js = out_dir / f"inertia_{t.name}.json"
    _plot(t, rows, png)
    write_json_atomic(js, document_header(
        schema_version, target=t.label,
        kind=t.kind, shape=t.shape, size=t.size, density=t.density, given_mass=t.given_mass,
        exact={"volume": t.volume, "mass": t.mass, "com": t.com, "inertia": t.inertia},
        rows=rows,
    ))
    return png, js


def _plot(t: Target, rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter, ScalarFormatter

    fig, axes = plt.subplots(1, 3, figsize=(13, 4.2), constrained_layout=True)
    styles = {"particles": ("o-", "C0"), "voxels": ("s-", "C1"), "polyhedron": ("^-", "C2")}
    panels = (("inertia_rel", "inertia tensor: ||I - I_exact||_F / ||I_exact||_F"),
              ("mass_rel", "mass: |m - m_exact| / m_exact"),
              ("com_rel", "COM: |c - c_exact| / bounding-box diagonal"))
    ticks = sorted({r["resolution"] for r in rows})
    for ax, (key, title) in zip(axes, panels):
        plotted = []
        for method, (style, colour) in styles.items():
            pts = [(r["resolution"], r[key]) for r in rows if r["method"] == method and r["samples"]
                   and math.isfinite(r[key]) and r[key] > tol.INERTIA_PLOT_NOISE_FLOOR]
            if pts:
                n, e = zip(*pts)
                plotted.extend(n)
                ax.loglog(n, e, style, color=colour, label=method, ms=4)
        if plotted:
            ref = np.array([min(plotted), max(plotted)], dtype=float)
            for order, ls in ((1, ":"), (2, "--")):
                ax.loglog(ref, 0.3 * (ref / ref[0]) ** -order, ls, color="0.5", lw=1, label=f"~ N^-{order}")
            ax.legend(fontsize=8)
        else:
            why = "a total mass was given" if key == "mass_rel" and t.given_mass else "by symmetry"
            ax.text(0.5, 0.5, f"exact for every method\n({why})", ha="center", va="center",
                    transform=ax.transAxes)
            ax.set_xscale("log")
            ax.set_xlim(min(ticks) / 1.2, max(ticks) * 1.2)
            ax.set_yticks([])
        ax.set_xticks(ticks)
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("resolution N")
        ax.set_ylabel("relative error")
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle(f"{t.label.split(';')[0]}\napproximations vs the exact result (N: cells along the "
                 "longest bounding-box side; polyhedron: segments around the axis)", fontsize=10)
    from io import BytesIO

    from ..results.io import write_bytes_atomic

    buf = BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    write_bytes_atomic(path, buf.getvalue())  # checked as every file freebody writes (results.io)
