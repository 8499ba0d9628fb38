"""The crack network as geometry: cracks as polylines, their junctions and their tips.

One :class:`CrackNetwork` describes what meshing, growth, hydraulics and output need to
know about the cracks of a problem without looking at the mesh:

* every crack is a polyline with its facet tag and its kind (``perforation``, ``natural``
  or ``path``, a bonded potential or grown crack);
* a *junction* is a crack end that lies on another crack (or on itself: a tip that curled
  back), where the mesh shares the vertex and the hydraulic network merges (docs/model.md §5);
* a *tip* is every other crack end away from the wellbore wall; a tip is *active* while it
  may still grow (growth paths) and inactive otherwise (natural-fracture ends, arrested or
  joined tips).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Sequence, Tuple

import numpy as np

KINDS = ("perforation", "natural", "path")


@dataclass
class CrackLine:
    """One crack: facet tag, kind (one of :data:`KINDS`) and its polyline (k >= 2 points)."""

    tag: int
    kind: str
    points: np.ndarray

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"crack {self.tag}: kind must be one of {KINDS}; got {self.kind!r}")
        self.points = np.asarray(self.points, dtype=float).reshape(-1, 2)
        if len(self.points) < 2:
            raise ValueError(f"crack {self.tag}: a polyline needs at least 2 points; got {len(self.points)}")

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())


@dataclass
class TipEnd:
    """A free crack end: which crack and end (0 first point, -1 last), position, outward
    direction (unit) and whether it may still grow."""

    tag: int
    end: int
    point: np.ndarray
    direction: np.ndarray
    active: bool


@dataclass
class CrackNetwork:
    """Cracks, junctions and tips of one geometry (see the module docstring)."""

    cracks: List[CrackLine] = field(default_factory=list)
    junctions: List[Tuple[np.ndarray, Tuple[int, int]]] = field(default_factory=list)
    tips: List[TipEnd] = field(default_factory=list)

    @classmethod
    def from_cracks(cls, cracks: Sequence[CrackLine], wellbore_radius: float = 0.0, growing: Sequence[int] = (),
                    tol: float = 1e-7) -> "CrackNetwork":
        """Find junctions and tips of ``cracks``.  Ends within ``tol`` of the wellbore wall
        (radius ``wellbore_radius`` about the origin) are neither; the last end of a crack
        tagged in ``growing`` is an active tip unless it is a junction."""
        net = cls(list(cracks))
        met = net._cracks_at_ends(tol)
        for k, c in enumerate(net.cracks):
            for e, end in enumerate((0, -1)):
                p = c.points[end]
                if wellbore_radius > 0 and abs(np.hypot(*p) - wellbore_radius) < tol:
                    continue
                other = met[2 * k + e]
                if other is not None:
                    seen = any(np.linalg.norm(q - p) < tol and set(tags) == {c.tag, other} for q, tags in net.junctions)
                    if not seen:  # two crack ends that meet are one junction
                        net.junctions.append((p.copy(), (c.tag, other)))
                    continue
                q = c.points[1] if end == 0 else c.points[-2]
                d = (p - q) / max(np.linalg.norm(p - q), 1e-300)
                # a path grows at its last end; a crack that is not a path (a natural fracture)
                # at both of its free ends
                active = c.tag in growing and (end == -1 or c.kind != "path")
                net.tips.append(TipEnd(c.tag, end, p.copy(), d, active=active))
        return net

    def _segments(self):
        """(a, b, crack, index): every segment a-b of every crack, the crack's position in
        :attr:`cracks` and the segment's index along it."""
        if not self.cracks:
            return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0, np.int64)
        a = np.concatenate([c.points[:-1] for c in self.cracks])
        b = np.concatenate([c.points[1:] for c in self.cracks])
        n = [len(c.points) - 1 for c in self.cracks]
        crack = np.repeat(np.arange(len(n)), n)
        return a, b, crack, np.arange(a.shape[0]) - np.repeat(np.cumsum(n) - n, n)

    def _cracks_at_ends(self, tol: float):
        """For each crack end (crack k's first end at 2 k, its last at 2 k + 1): the tag of the
        first crack whose polyline passes within ``tol`` of it, or None; for the crack's own
        polyline only its segments short of that end (not its two segments there).  One pass
        over every end and every segment (:meth:`_segments`)."""
        a, b, crack, index = self._segments()
        if not self.cracks:
            return []
        p = np.stack([c.points[end] for c in self.cracks for end in (0, -1)])  # (m, 2)
        e = b - a
        w = p[:, None, :] - a[None]  # (m, s, 2)
        u = np.clip((w[..., 0] * e[:, 0] + w[..., 1] * e[:, 1]) / np.maximum(e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1],
                                                                          1e-300), 0, 1)
        r = a[None] + u[..., None] * e[None] - p[:, None, :]
        near = np.sqrt(r[..., 0] * r[..., 0] + r[..., 1] * r[..., 1]) < tol
        me = np.repeat(np.arange(len(self.cracks)), 2)
        n_me = np.array([len(c.points) - 1 for c in self.cracks])[me]
        last = np.tile([False, True], len(self.cracks))
        short = np.where(last[:, None], index[None] < n_me[:, None] - 2, index[None] >= 2)
        near &= (crack[None] != me[:, None]) | short
        first = near.argmax(axis=1)
        return [self.cracks[crack[f]].tag if near[i, f] else None for i, f in enumerate(first)]

    def counts(self) -> dict:
        """What a summary reports: cracks, junctions, tips and active tips."""
        return {"cracks": len(self.cracks), "junctions": len(self.junctions), "tips": len(self.tips),
                "active_tips": sum(t.active for t in self.tips)}

    def as_dict(self) -> dict:
        """JSON-able description (``growth.json``, checkpoints)."""
        return {"cracks": [{"tag": c.tag, "kind": c.kind, "points": c.points.tolist()} for c in self.cracks],
                "junctions": [{"point": p.tolist(), "tags": list(t)} for p, t in self.junctions],
                "tips": [{"tag": t.tag, "end": t.end, "point": t.point.tolist(), "direction": t.direction.tolist(),
                          "active": bool(t.active)} for t in self.tips]}
