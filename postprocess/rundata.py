"""What the figures, charts and animation read from one output folder of a run.

A run folder (``results/<scenario>`` or ``--out DIR``) holds

* ``<name>.pvd``: the frames, each with a ``bulk`` part (DG fields on triangles)
  and, where the scenario has cracks, a ``cracks`` part (a line mesh through the
  Gauss points of every interface facet);
* ``history.csv``: energy budget and scenario columns (``p_h``, lengths, ...)
  every few steps;
* ``summary.json``: the closing summary (mesh, timing, energy, accuracy).

:func:`load_run` reads the last two and the frame list; :func:`crack_statistics`
integrates the crack fields of every frame along the facets (lengths, contact
mode fractions, largest opening and penetration).  Only the crack statistics
need VTK (pyvista); the rest is the standard library and NumPy.
"""
from __future__ import annotations

import csv
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from hydrofrac.riemann import mode_fractions

from .snapshot import find_pvd, read_frames

#: contact modes of the ``mode`` field (argmax of the mode fractions, hydrofrac.interface)
MODES = ("bonded", "stick", "slip", "separated")
#: facets with a mean damage at least this are drawn and counted as cracks
CRACK_DAMAGE = 0.5


@dataclass
class Run:
    """One output folder: its ``.pvd``, frames, history columns and summary."""

    dir: Path
    pvd: Path
    frames: List[Tuple[float, Dict[str, Path]]]
    history: Dict[str, np.ndarray] = field(default_factory=dict)
    summary: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.summary.get("scenario", self.pvd.stem)

    @property
    def t_end(self) -> float:
        return self.frames[-1][0]

    @property
    def has_cracks(self) -> bool:
        return any("cracks" in parts for _, parts in self.frames)

    def history_at(self, column: str, t: float) -> Optional[float]:
        """A history column interpolated to time t (None if the history lacks it)."""
        if column not in self.history or "t" not in self.history:
            return None
        return float(np.interp(t, self.history["t"], self.history[column]))


def load_run(source: Union[str, Path]) -> Run:
    """The run in an output folder (or of a ``.pvd`` file)."""
    pvd = find_pvd(source)
    run = Run(dir=pvd.parent, pvd=pvd, frames=read_frames(pvd))
    hist = pvd.parent / "history.csv"
    if hist.is_file():
        run.history = read_history(hist)
    summ = pvd.parent / "summary.json"
    if summ.is_file():
        run.summary = json.loads(summ.read_text())
    return run


def read_history(path: Path) -> Dict[str, np.ndarray]:
    """Columns of ``history.csv`` as float arrays (rows of a restarted run that
    repeat earlier steps are dropped, keeping the later ones)."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return {}
    cols = {k: np.array([float(r[k]) if r.get(k) not in (None, "") else np.nan for r in rows]) for k in rows[0]}
    if "step" in cols:
        # a restart appends from its checkpoint: keep the last row of every step, in step order
        _, last = np.unique(cols["step"][::-1], return_index=True)
        keep = np.sort(len(rows) - 1 - last)
        cols = {k: v[keep] for k, v in cols.items()}
    return cols


# ---------------------------------------------------------------------------- times
def parse_time(text: Union[str, float]) -> float:
    """Seconds from ``'5.6e-4'``, ``'560us'``, ``'560µs'``, ``'0.56ms'`` or ``'0.00056s'``."""
    if isinstance(text, (int, float)):
        return float(text)
    m = re.fullmatch(r"\s*([-+0-9.eE]+)\s*(s|ms|us|µs|μs)?\s*", text)
    if not m:
        raise ValueError(f"cannot read the time '{text}': give seconds (5.6e-4) or a number with a unit "
                         "(560us, 0.56ms)")
    scale = {None: 1.0, "s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "μs": 1e-6}[m.group(2)]
    return float(m.group(1)) * scale


def time_unit(t_end: float) -> Tuple[float, str]:
    """(scale, unit) for time axes: µs for runs shorter than 2 ms, else ms."""
    return (1e-6, "µs") if t_end < 2e-3 else (1e-3, "ms")


def load_breakpoints(run: Run) -> Optional[Tuple[float, float, float]]:
    """(start of removal, fully removed, start of re-loading) of a p_h history that
    falls and rises again (re-fracturing), or None."""
    if "p_h" not in run.history:
        return None
    t, p = run.history["t"], run.history["p_h"]
    peak = np.nanmax(p)
    top = np.flatnonzero(p >= peak - 1e-6 * abs(peak))
    if top.size == 0:
        return None
    first_drop = np.flatnonzero((np.arange(p.size) > top[0]) & (p < peak - 1e-3 * abs(peak)))
    if first_drop.size == 0:
        return None
    i_hold = first_drop[0] - 1
    low = p[i_hold:].min()
    at_low = i_hold + np.flatnonzero(p[i_hold:] <= low + 1e-3 * abs(peak))
    rises = np.flatnonzero((np.arange(p.size) > at_low[0]) & (p > low + 1e-3 * abs(peak)))
    if rises.size == 0:
        return None
    at_low = at_low[at_low < rises[0]]
    return float(t[i_hold]), float(t[at_low[0]]), float(t[at_low[-1]])


def wall_time_parts(summary: dict) -> List[Tuple[str, float]]:
    """Where a run's wall time went, from its summary: (part, seconds) for each entry of the
    time split (the largest rank's) but the set-up, which is outside the wall time; a remesh's
    parts (``remeshing.split_per_remesh_s`` times the remeshes) in place of "remesh" where the
    summary has them; and what no timer covers (the loop, the fallback state, history), the wall time
    less the rest.  Largest first; the parts add up to the wall time unless the ranks' largest
    parts overlap by more than that remainder (it is then 0)."""
    split = dict(summary.get("time_split_s", {}))
    split.pop("setup", None)
    rm = summary.get("remeshing", {})
    per = rm.get("split_per_remesh_s")
    if per and "remesh" in split:
        split.pop("remesh")
        split.update({f"remesh: {k}": v * rm["remeshes"] for k, v in per.items()})
    parts = sorted(split.items(), key=lambda kv: -kv[1])
    wall = float(summary.get("wall_time_s", 0.0))
    return parts + [("not timed", max(wall - sum(v for _, v in parts), 0.0))]


def key_times(run: Run) -> List[float]:
    """Times worth a picture, in the spirit of the paper's sequences.

    * crack intersection (``accuracy.intersection_time`` in the summary): before
      it, at it, when half and when all of the natural fracture carries load
      (``nf_loaded_length`` in the history), and at the end (figs. 7-9);
    * a load that is removed and re-applied (re-fracturing, figs. 11-12): during
      the removal, twice while the cracks close (``separated_fraction`` of the
      history below 0.9 and 0.4), just before the re-loading, while the cracks
      re-open (half-way back to all separated), and at the end;
    * otherwise four frames evenly spread over the run.
    """
    t_end = run.t_end
    acc = run.summary.get("accuracy", {})
    t_int = acc.get("intersection_time")
    if t_int is not None and np.isfinite(t_int) and 0 < t_int < t_end:
        times = [0.75 * t_int, t_int + 0.02 * (t_end - t_int)]  # before it, just after it
        nf, lf = acc.get("nf_length"), run.history.get("nf_loaded_length")
        if nf and lf is not None:
            for share in (0.5, 0.99):
                hit = np.flatnonzero(lf >= share * nf)
                if hit.size:
                    times.append(float(run.history["t"][hit[0]]))
        times.append(t_int + 0.3 * (t_end - t_int))
        return sorted(set(times + [t_end]))
    bp = load_breakpoints(run)
    if bp is not None:
        t_hold, t_off, t_on = bp
        times = [0.5 * (t_hold + t_off), t_on - 0.05 * (t_on - t_off), t_end]
        sep = run.history.get("separated_fraction")
        t = run.history["t"]
        closing = [] if sep is None else [np.flatnonzero((t > t_off) & (t < t_on) & (sep < share)) for share in
                                          (0.9, 0.4)]
        if closing and all(c.size for c in closing):
            times += [float(t[c[0]]) for c in closing]
        else:
            times += [t_off, t_off + 0.25 * (t_on - t_off)]
        before = None if sep is None else sep[t <= t_on]
        opening = (np.array([], dtype=int) if before is None or before.size == 0 else
                   np.flatnonzero((t > t_on) & (sep > 0.5 * (before[-1] + 1.0))))
        times.append(float(t[opening[0]]) if opening.size else t_on + 0.4 * (t_end - t_on))
        return sorted(times)
    return [t_end * k / 4 for k in (1, 2, 3, 4)]


def select_frames(run: Run, times: Optional[Sequence[Union[str, float]]] = None,
                  count: Optional[int] = None) -> List[Tuple[float, Dict[str, Path]]]:
    """The frames nearest to ``times`` (seconds or '560us'), to ``count`` times evenly
    spread over the run (t_end k / count, k = 1..count: the last frame always, the
    initial one never), or to :func:`key_times`."""
    frames = run.frames
    if times:
        wanted = [parse_time(t) for t in times]
    elif count:
        t0, t1 = frames[0][0], frames[-1][0]
        wanted = [t0 + (t1 - t0) * k / count for k in range(1, count + 1)]
    else:
        wanted = key_times(run)
    out = []
    for t in wanted:
        f = min(frames, key=lambda fr: abs(fr[0] - t))
        if f not in out:
            out.append(f)
    return sorted(out, key=lambda fr: fr[0])


def subsample(frames, n: int):
    """At most n frames, evenly spread, first and last kept."""
    if len(frames) <= n:
        return list(frames)
    idx = np.unique(np.round(np.linspace(0, len(frames) - 1, n)).astype(int))
    return [frames[i] for i in idx]


# ---------------------------------------------------------------------------- cracks
def segment_values(grid, name: str) -> np.ndarray:
    """Per line segment of a cracks part: the mean of a point field at its two ends."""
    conn = grid.cells.reshape(-1, 3)[:, 1:]
    return np.asarray(grid.point_data[name])[conn].mean(axis=1)


def segment_lengths(grid) -> np.ndarray:
    conn = grid.cells.reshape(-1, 3)[:, 1:]
    pts = np.asarray(grid.points)
    return np.linalg.norm(pts[conn[:, 1]] - pts[conn[:, 0]], axis=1)


def crack_frame_statistics(grid) -> Dict[str, float]:
    """Integrals along the interface facets of one cracks frame.

    interface_length : all interface facets (perforations, natural fractures, potential paths) [m]
    damaged_length : ∫ D ds, the debonded length [m]
    network_length, loaded_length : ∫ network ds and ∫ f_p ds (hydraulically loaded runs) [m]
    fraction_<mode> : share of the interface length in each contact mode, from the
        model's mode fractions 1 − D, D η γ, D η (1 − γ), D (1 − η) (they add up to one)
    opening_max, opening_min : largest and smallest opening δ at the Gauss points [m]
    penetration_ratio_max : largest penetration −δ relative to the permitted |δ'₀| δ̃ of its
        crack (the output's ``penetration_limit``, from the model parameters); > 1 is a violation
    """
    ell = segment_lengths(grid)
    total = float(ell.sum())
    D = segment_values(grid, "D")
    out = {"interface_length": total, "damaged_length": float((D * ell).sum())}
    for name, key in (("network", "network_length"), ("f_p", "loaded_length")):
        if name in grid.point_data:
            out[key] = float((segment_values(grid, name) * ell).sum())
    if "eta" in grid.point_data and "gamma" in grid.point_data:
        eta, gamma = segment_values(grid, "eta"), segment_values(grid, "gamma")
        parts = mode_fractions(D, eta, gamma)
        for i, mode in enumerate(MODES):
            out[f"fraction_{mode}"] = float((parts[..., i] * ell).sum() / max(total, 1e-300))
    delta = np.asarray(grid.point_data["opening"])
    out["opening_max"] = float(delta.max())
    out["opening_min"] = float(delta.min())
    if "penetration_limit" in grid.point_data:  # |δ'₀| δ̃ of each crack, from the model parameters
        limit = np.asarray(grid.point_data["penetration_limit"])
        out["penetration_ratio_max"] = float(np.max(np.maximum(-delta, 0.0) / limit))
    return out


def crack_statistics(run: Run, max_frames: Optional[int] = None) -> Dict[str, np.ndarray]:
    """:func:`crack_frame_statistics` of every frame (or ``max_frames`` of them), as
    columns with the time ``t``; empty if the run has no cracks part."""
    import pyvista as pv
    frames = [f for f in run.frames if "cracks" in f[1]]
    if max_frames:
        frames = subsample(frames, max_frames)
    rows = [dict(t=t, **crack_frame_statistics(pv.read(parts["cracks"]))) for t, parts in frames]
    if not rows:
        return {}
    return {k: np.array([r.get(k, np.nan) for r in rows]) for k in rows[0]}


def tool_main(name: str, make) -> int:
    """The exit of a postprocessing command: run ``make()`` (it returns a path or a list of
    paths), print what it wrote, one per line, and return 0; on a missing file or bad input,
    print ``name: reason`` on stderr and return 2."""
    import sys
    try:
        out = make()
    except (FileNotFoundError, KeyError, ValueError) as err:
        print(f"{name}: {err}", file=sys.stderr)
        return 2
    for p in out if isinstance(out, (list, tuple)) else [out]:
        print(p)
    return 0


def write_csv(path, rows):
    """Rows (dicts) as CSV, floats with 6 significant digits: the benchmark and study tables
    in ``postprocess/results``.  The columns are the rows' keys in order of first appearance;
    a row without one leaves its cell empty."""
    fields = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
