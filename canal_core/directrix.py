"""The directrix (spine curve) of the canal (paper Section 4.1, "Estimating the Directrix")."""

from __future__ import annotations

import numpy as np

from .validation import FloatArray


def directrix_mean(aligned: FloatArray) -> FloatArray:
    """Arithmetic mean of the aligned demonstrations (Alg. 1, line 4).

    Parameters
    ----------
    aligned : array, shape (n, N, D)

    Returns
    -------
    directrix : array, shape (N, D)
    """
    return aligned.mean(axis=0)


def default_gmr_components(n_samples: int) -> int:
    """Components for the GMR directrix: the paper's 4 for short skills, one per ~20 samples up to 15."""
    return int(np.clip(n_samples // 20, 4, 15))


def directrix_gmr(
    aligned: FloatArray, n_components: int | None = None, random_state: int = 0
) -> FloatArray:
    """Directrix regressed by GMM/GMR over the phase s in [0, 1] (Calinon et al. 2007).

    A GMM is fitted to (s, x) of every aligned sample and the conditional mean E[x | s] is
    read at the N phases. Deterministic for a given ``random_state``.

    Parameters
    ----------
    aligned : array, shape (n, N, D)
    n_components : int, optional
        Defaults to :func:`default_gmr_components`.
    random_state : int

    Returns
    -------
    directrix : array, shape (N, D)
    """
    from gmr import GMM  # imported here: only this option needs it

    n, n_samples, dim = aligned.shape
    phase = np.linspace(0.0, 1.0, n_samples)
    samples = np.column_stack([np.tile(phase, n), aligned.reshape(-1, dim)])
    k = default_gmr_components(n_samples) if n_components is None else n_components
    gmm = GMM(n_components=k, random_state=random_state)
    # kmeans++ initialisation makes EM converge to the same local optimum run after run.
    gmm.from_samples(samples, init_params="kmeans++")
    predicted = gmm.predict(np.array([0]), phase[:, None])
    return np.asarray(predicted, dtype=np.float64)
