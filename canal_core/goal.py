"""Moving the end of the canal to a new goal: a smooth displacement of the canal.

The paper reproduces towards the demonstrations' own end. To reach another goal g, the
canal itself is deformed, in the spirit of the generalized-cylinder follow-up (Ahmadzadeh &
Chernova 2018, which adapts the directrix and carries the cross-sections with it): every
directrix point is displaced by

    d(s) = S(s / L) (g - c_{N-1}),    S(x) = 10 x^3 - 15 x^4 + 6 x^5,

where s is the arc length and L the canal's length. S rises from 0 at the first section
(the start region is untouched, with zero slope and curvature there) to 1 at the last (the
end moves exactly onto g), so the displacement adds no jerk at either end. Frames are
recomputed on the displaced directrix and each section keeps its shape and size in its
(new) plane: the deformed canal is a canal of the same kind, reproduction by the ratio rule
stays inside it by construction, and with the end decay of the ratio rule it ends on g.
"""

from __future__ import annotations

import numpy as np

from .reproduce import smootherstep
from .validation import FloatArray


def goal_displacements(arclength: FloatArray, shift: FloatArray) -> FloatArray:
    """Displacement of every directrix point, shape (N, D), moving the last one by ``shift`` (D,).

    Parameters
    ----------
    arclength : array, shape (N,)
    shift : array, shape (D,)
        goal - c_{N-1}.
    """
    total = float(arclength[-1])
    weight = smootherstep(arclength / total) if total > 0.0 else np.ones_like(arclength)
    return np.asarray(weight[:, None] * shift[None, :], dtype=np.float64)
