"""Pictures of a canal: demonstrations, directrix, the canal surface and reproductions.

Needs matplotlib (the optional extra ``plot``: ``pip install 'canal-lfd[plot]'``); nothing
else in canal_core imports this module. ::

    from canal_core.plot import plot_canal
    fig = plot_canal(canal, demos=demos, starts=4, seed=1)
    fig.savefig("canal.png")

2-D canals are drawn as a filled strip, 3-D canals as a translucent tube with every few
cross-section rings outlined. ``examples/render_figure.py`` (the README picture) is built
from the same panel functions.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .errors import InvalidInputError
from .model import Canal
from .validation import FloatArray

DEMO: dict[str, Any] = dict(color="black", lw=1.2, label="demonstrations")
DIRECTRIX: dict[str, Any] = dict(color="tab:blue", lw=1.6, label="directrix")
REPRO: dict[str, Any] = dict(color="tab:orange", lw=1.2, ls=(0, (3, 1.5)), label="reproductions")
START: dict[str, Any] = dict(color="tab:red", s=14, zorder=5, label="starts")
SURFACE = "0.55"
VIEW = (20.0, -40.0)  # elevation, azimuth (degrees) of 3-D panels


def _pyplot() -> Any:
    try:
        import matplotlib.pyplot as plt
    except ImportError as exc:  # an optional extra: say how to get it
        raise ImportError("canal_core.plot needs matplotlib: pip install 'canal-lfd[plot]' "
                          f"(or pip install matplotlib) ({exc})") from None
    return plt


def random_starts(canal: Canal, n: int, rng: np.random.Generator,
                  head: float = 0.05) -> FloatArray:
    """``n`` random points inside the canal near its start (its first ``head`` of sections).

    Rejection sampling: uniform in the ball of a section's largest radius around a directrix
    sample near the start, kept when the canal contains it.

    Returns
    -------
    starts : array, shape (n, D)
    """
    k = max(1, round(head * canal.n_sections))
    found: list[FloatArray] = []
    for _ in range(1000):
        i = rng.integers(0, k, size=4 * n)
        u = rng.standard_normal((4 * n, canal.dim))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        u *= rng.uniform(0.0, 1.0, (4 * n, 1)) ** (1.0 / canal.dim)
        points = canal.directrix[i] + canal.radii[i, None] * u
        found.extend(points[canal.contains(points)])
        if len(found) >= n:
            return np.array(found[:n], dtype=np.float64)
    raise InvalidInputError("could not sample starts inside the canal", field="starts")


def _starts(canal: Canal, starts: int | Sequence[Any] | FloatArray | None,
            seed: int) -> FloatArray:
    if starts is None:
        return np.empty((0, canal.dim))
    if isinstance(starts, int | np.integer):
        return random_starts(canal, int(starts), np.random.default_rng(seed))
    arr = np.asarray(starts, dtype=np.float64).reshape(-1, canal.dim) if len(starts) else \
        np.empty((0, canal.dim))
    if not np.all(np.isfinite(arr)):
        raise InvalidInputError("expected finite start points", field="starts")
    return arr


def draw_canal_3d(ax: Any, canal: Canal, n_angles: int = 36, n_rings: int = 16) -> None:
    """The canal as a translucent tube with ``n_rings`` cross-section outlines, on a 3-D axes."""
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    mesh = canal.mesh(n_angles=n_angles)
    rings = mesh.vertices[: canal.n_sections * n_angles].reshape(canal.n_sections, n_angles, 3)
    tris = list(mesh.vertices[mesh.faces])
    step = max(1, canal.n_sections // max(n_rings, 1))
    outlines = [rings[i] for i in range(0, canal.n_sections, step)] + [rings[-1]]
    # The end sections are extruded along the tangent by end_depths (demos rarely start
    # exactly in the first section plane); draw those short tubes too.
    for ring, shift in ((rings[0], -canal.end_depths[0] * canal.tangents[0]),
                        (rings[-1], canal.end_depths[1] * canal.tangents[-1])):
        if np.linalg.norm(shift) > 1e-6 * canal.radii.max():
            nxt = np.roll(ring, -1, axis=0)
            tris.extend(np.stack([ring, nxt, nxt + shift, ring + shift], axis=1))
            outlines.append(ring + shift)
    # Data limits come from the vertices, not from the collections: matplotlib's 3-D
    # autoscale of a collection gave NaN limits (a ValueError) in 4 of 30 figures drawn in
    # one process.
    ax.add_collection3d(Poly3DCollection(tris, facecolor=SURFACE, edgecolor="none", alpha=0.12),
                        autolim=False)
    closed = [np.vstack([r, r[:1]]) for r in outlines]
    ax.add_collection3d(Line3DCollection(closed, colors=SURFACE, linewidths=0.6), autolim=False)
    ax.auto_scale_xyz(*np.vstack([mesh.vertices, *outlines]).T, had_data=True)


def draw_canal_2d(ax: Any, canal: Canal) -> None:
    """The canal as a filled strip (its 2-D mesh, with the extruded ends)."""
    from matplotlib.collections import PolyCollection

    mesh = canal.mesh()
    polys = list(mesh.vertices[mesh.faces][:, :, :2])
    flat = mesh.vertices[:, :2]
    for (a, b), shift in (((flat[0], flat[1]), -canal.end_depths[0] * canal.tangents[0]),
                          ((flat[-2], flat[-1]), canal.end_depths[1] * canal.tangents[-1])):
        polys.append(np.array([a, b, b + shift, a + shift]))
    ax.add_collection(PolyCollection(polys, facecolor=SURFACE, edgecolor="none", alpha=0.35,
                                     label="canal"))


def draw_paths(ax: Any, canal: Canal, demos: Sequence[Any] = (),
               starts: FloatArray | None = None) -> list[FloatArray]:
    """Demonstrations (black), directrix (blue), reproductions from ``starts`` (orange, the
    starts in red). Returns the reproduced trajectories, each (N', D)."""
    for j, d in enumerate(demos):
        ax.plot(*np.asarray(d, dtype=np.float64).T, **(DEMO if j == 0 else {**DEMO, "label": None}))
    ax.plot(*canal.directrix.T, **DIRECTRIX)
    paths: list[FloatArray] = []
    if starts is not None and len(starts):
        for j, s in enumerate(starts):
            path = canal.reproduce(s)
            paths.append(path)
            ax.plot(*path.T, **(REPRO if j == 0 else {**REPRO, "label": None}))
        extra = {"depthshade": False} if canal.dim == 3 else {}
        ax.scatter(*np.asarray(starts).T, **START, **extra)
    return paths


def draw_panel(ax: Any, canal: Canal, demos: Sequence[Any] = (),
               starts: FloatArray | None = None, title: str | None = None,
               limits: FloatArray | None = None,
               view: tuple[float, float] = VIEW) -> list[FloatArray]:
    """One panel: canal, demos, directrix and reproductions, on a 2-D or 3-D axes to match the
    canal. ``limits`` (2, 3) fixes a common scale for 3-D panels; returns the reproductions."""
    if canal.dim == 3:
        draw_canal_3d(ax, canal)
        paths = draw_paths(ax, canal, demos, starts)
        lo, hi = canal.bounds if limits is None else limits
        pad = 0.05 * float((hi - lo).max())
        ax.set(xlim=(lo[0] - pad, hi[0] + pad), ylim=(lo[1] - pad, hi[1] + pad),
               zlim=(lo[2] - pad, hi[2] + pad), xlabel="x", ylabel="y", zlabel="z")
        ax.set_box_aspect((2.4, 1.0, 1.0), zoom=1.25)
        ax.view_init(elev=view[0], azim=view[1])
        ax.tick_params(labelsize=6, pad=0)
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.label.set_size(8)
            axis.labelpad = -4
    else:
        draw_canal_2d(ax, canal)
        paths = draw_paths(ax, canal, demos, starts)
        ax.set_aspect("equal")
        ax.autoscale_view()
        ax.tick_params(labelsize=7)
    if title:
        ax.set_title(title, fontsize=10)
    return paths


def plot_canal(canal: Canal, demos: Sequence[Any] = (),
               starts: int | Sequence[Any] | FloatArray | None = None, *, seed: int = 0,
               title: str | None = None, ax: Any = None,
               figsize: tuple[float, float] = (6.4, 4.8)) -> Any:
    """A figure of ``canal`` with its demonstrations and reproductions.

    Parameters
    ----------
    canal : Canal
    demos : sequence of arrays, shape (T_j, D), optional
    starts : int, or array, shape (M, D), optional
        Start points to reproduce from, or how many random starts inside the canal near its
        beginning to draw (seeded by ``seed``).
    title : str, optional
        Defaults to the canal's one-line summary.
    ax : matplotlib axes, optional
        Draw there (a 3-D axes for a 3-D canal) instead of on a new figure.

    Returns
    -------
    figure : matplotlib.figure.Figure
    """
    points = _starts(canal, starts, seed)
    if ax is None:
        plt = _pyplot()
        fig = plt.figure(figsize=figsize, layout="constrained")
        ax = fig.add_subplot(projection="3d" if canal.dim == 3 else None)
    draw_panel(ax, canal, demos, points, title=str(canal) if title is None else title)
    ax.legend(loc="best", fontsize=7, frameon=False)
    return ax.get_figure()


__all__ = ["draw_canal_2d", "draw_canal_3d", "draw_panel", "draw_paths", "plot_canal",
           "random_starts"]
