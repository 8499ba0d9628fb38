"""Work models of the studies: what a scheme would save, computed from a mesh's cell time steps."""
from __future__ import annotations

import numpy as np


def lts_gain(dt_cells, dt_global, levels):
    """Work of local time stepping relative to the global step ``dt_global``: ideal per-cell
    steps ``dt_cells``, and 2^k levels (at most ``levels``); with the finest level's share."""
    ratio = dt_cells / dt_global
    k = np.minimum(np.floor(np.log2(ratio + 1e-12)).astype(int), levels - 1)
    k = np.maximum(k, 0)
    work_levels = float(np.mean(2.0 ** -k))
    work_ideal = float(np.mean(1.0 / ratio))
    return {"work_ideal": work_ideal, "speedup_ideal": 1.0 / work_ideal,
            "work_levels": work_levels, "speedup_levels": 1.0 / work_levels,
            "finest_level_share": float(np.mean(k == 0)),
            "levels_used": int(k.max()) + 1,
            "dt_max_over_min": float(ratio.max())}
