"""Time-series charts of a run (matplotlib): what a reader needs to trust it.

    python -m hydrofrac.postprocess.charts results/intersection_regularized
    python -m hydrofrac.postprocess.charts RUN --out charts --max-frames 60

From ``history.csv`` (every few steps) and ``summary.json``:

* ``pressure.png``: the hydraulic pressure p_h(t);
* ``energy_budget.png``: kinetic and strain energy, work in, radiated energy,
  energy dissipated by the upwind flux, by friction and by damage, and the
  balance error (all relative to the initial stress state, J per metre of
  thickness);

from the ``cracks`` part of the frames (integrated along the facets, see
:func:`hydrofrac.postprocess.rundata.crack_frame_statistics`), drawn as markers:

* ``crack_length.png``: debonded length ∫D ds, network length ∫network ds and
  loaded length ∫f_p ds (the history's ``network_length``, ``nf_loaded_length`` and, with a
  finite fluid, ``wet_length`` columns, where the scenario records them, as lines);
* ``contact_modes.png``: the share of the interface length in each contact mode
  (bonded 1 − D, stick D η γ, slip D η (1 − γ), separated D (1 − η));
* ``opening.png``: the largest opening, and the largest penetration relative to the
  permitted one, −δ / (|δ'₀| δ̃) with each crack's δ̃ (the frames' ``penetration_limit``,
  written from the model parameters, never from the data): above 1 is a violation.

* ``wall_time.png``: where the wall time went (the summary's time split, a remesh's parts
  apart), with the run's DOF·stages/s and energy-balance error (relative to the initial
  energy, the work in and the radiated energy).

``charts.png`` has all of them on one page.  The crossing of the natural fracture
(``accuracy.intersection_time``) is a dotted line; a load-off interval (p_h
removed and re-applied) is shaded.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import List, Optional

import numpy as np

from . import rundata
from .rundata import MODES, Run, load_run

ENERGY_TERMS = (("kinetic", "kinetic", "C0"), ("strain", "strain", "C1"), ("radiated", "radiated", "C2"),
                ("dissipated_flux", "dissipated: upwind flux", "C4"),
                ("dissipated_friction", "dissipated: friction", "C5"),
                ("dissipated_damage", "dissipated: damage", "C3"))
MODE_COLOURS = {"bonded": "#9e9e9e", "stick": "#2c7bb6", "slip": "#fdae61", "separated": "#d7191c"}


def pyplot():
    """matplotlib.pyplot with the Agg backend (files only, no display)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


class Charts:
    """The charts of one run; each ``draw_*`` method fills one matplotlib Axes."""

    def __init__(self, run: Run, max_frames: Optional[int] = None):
        self.run = run
        self.h = run.history
        self.scale, self.unit = rundata.time_unit(run.t_end)
        self.cracks = rundata.crack_statistics(run, max_frames) if run.has_cracks else {}

    # -- helpers
    def _t(self, t):
        return np.asarray(t) / self.scale

    def _events(self, ax, shade=True):
        """Mark the intersection time and a load-off interval (shaded, or its ends as lines)."""
        t_int = self.run.summary.get("accuracy", {}).get("intersection_time")
        if t_int is not None and np.isfinite(t_int):
            ax.axvline(t_int / self.scale, color="k", ls=":", lw=1, label="crack intersection")
        bp = rundata.load_breakpoints(self.run)
        if bp is not None:
            if shade:
                ax.axvspan(bp[1] / self.scale, bp[2] / self.scale, color="0.9", zorder=0, label="load off")
            else:
                for k, t in enumerate(bp[1:]):
                    ax.axvline(t / self.scale, color="k", ls=":", lw=1, label="load off / on" if k == 0 else None)

    def _finish(self, ax, ylabel, title, legend=True):
        ax.set_xlabel(f"time t [{self.unit}]")
        ax.set_ylabel(ylabel)
        ax.set_title(title, fontsize=11)
        ax.set_xlim(0, self.run.t_end / self.scale)
        ax.grid(alpha=0.3)
        if legend and ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8, loc="best", framealpha=0.85)

    @staticmethod
    def _missing(ax, text, title=None):
        """An empty panel that says why (and keeps its title)."""
        ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, fontsize=9, color="0.3",
                wrap=True)
        ax.set_xticks([])
        ax.set_yticks([])
        if title:
            ax.set_title(title, fontsize=11)

    # -- the charts
    def draw_pressure(self, ax):
        if "p_h" not in self.h:
            self._missing(ax, "no hydraulic pressure in history.csv\n(this scenario has no p_h)",
                          "hydraulic pressure")
            return
        self._events(ax)
        ax.plot(self._t(self.h["t"]), self.h["p_h"] / 1e6, color="C0", lw=1.8, label="p_h")
        ax.set_ylim(bottom=min(0.0, float(np.nanmin(self.h["p_h"])) / 1e6))
        self._finish(ax, "p_h [MPa]", "hydraulic pressure p_h(t)")

    def draw_energy(self, ax):
        h = self.h
        if "kinetic" not in h:
            self._missing(ax, "no energy columns in history.csv")
            return
        t = self._t(h["t"])
        self._events(ax)
        initial = float(self.run.summary.get("energy", {}).get("initial", h["kinetic"][0] + h["strain"][0]))
        supplied = initial + h.get("work_in", np.zeros_like(t))
        label = "work in" if initial == 0 else "initial + work in"
        ax.plot(t, supplied, color="k", lw=2.2, label=label)
        for key, name, colour in ENERGY_TERMS:
            if key in h:
                ax.plot(t, np.where(h[key] > 0, h[key], np.nan), color=colour, lw=1.4, label=name)
        if "balance_error" in h:
            err = np.abs(h["balance_error"])
            ax.plot(t, np.where(err > 0, err, np.nan), color="0.4", lw=1, ls="--", label="|balance error|")
        top = float(np.nanmax(np.abs(supplied))) if np.isfinite(supplied).any() else 1.0
        ax.set_yscale("log")
        ax.set_ylim(max(top, 1e-300) * 1e-5, top * 3)
        self._finish(ax, "energy [J/m]", "energy budget (per metre of thickness)")
        ax.legend(fontsize=7.5, loc="best", framealpha=0.85, ncol=2)

    def draw_lengths(self, ax):
        h, c = self.h, self.cracks
        drew = False
        self._events(ax)
        if "network_length" in h:
            ax.plot(self._t(h["t"]), h["network_length"], color="C0", lw=1.6, label="network length (history)")
            drew = True
        if "nf_loaded_length" in h:
            ax.plot(self._t(h["t"]), h["nf_loaded_length"], color="C3", lw=1.6,
                    label="loaded length of the natural fracture, ∫f_p ds (history)")
            drew = True
        if "wet_length" in h and "fluid_volume" in h and np.isfinite(np.asarray(h["fluid_volume"], float)).all():
            ax.plot(self._t(h["t"]), h["wet_length"], color="C4", lw=1.6, label="wet length: the fluid's reach (history)")
            drew = True
        if c:
            ct = self._t(c["t"])
            ax.plot(ct, c["damaged_length"], "o", ms=3.5, color="C2", mfc="none", label="debonded length ∫D ds")
            if "network_length" in c and "network_length" not in h:
                ax.plot(ct, c["network_length"], "s", ms=3, color="C0", mfc="none", label="network length")
            if "loaded_length" in c:
                ax.plot(ct, c["loaded_length"], "^", ms=3.5, color="C1", mfc="none", label="loaded length ∫f_p ds")
            drew = True
        if not drew:
            self._missing(ax, "no crack lengths: the run has no cracks part\nand no length columns in history.csv",
                          "crack lengths")
            return
        ax.set_ylim(bottom=0)
        self._finish(ax, "length [m]", "crack and loaded lengths")

    def draw_modes(self, ax):
        c = self.cracks
        if not c or "fraction_bonded" not in c:
            self._missing(ax, "no contact modes: the run has no cracks part", "contact modes")
            return
        ct = self._t(c["t"])
        ax.stackplot(ct, *[np.clip(c[f"fraction_{m}"], 0, 1) for m in MODES], labels=MODES,
                     colors=[MODE_COLOURS[m] for m in MODES])
        self._events(ax, shade=False)
        ax.set_ylim(0, 1)
        self._finish(ax, "share of interface length", "contact modes along the interfaces", legend=False)
        ax.legend(fontsize=8, loc="lower left", framealpha=0.9)

    def draw_opening(self, ax):
        c = self.cracks
        if not c:
            self._missing(ax, "no opening: the run has no cracks part", "largest opening")
            return
        self._events(ax)
        ax.plot(self._t(c["t"]), c["opening_max"] * 1e3, "o-", ms=3, lw=1.4, color="C0", label="max opening δ")
        ax.set_ylim(bottom=0)
        self._finish(ax, "opening [mm]", "largest crack opening")

    def draw_penetration(self, ax):
        c = self.cracks
        if not c:
            self._missing(ax, "no penetration: the run has no cracks part", "largest penetration")
            return
        self._events(ax)
        if "penetration_ratio_max" not in c:
            self._missing(ax, "the frames carry no penetration_limit (written by older runs)", "largest penetration")
            return
        ratio = c["penetration_ratio_max"]
        ax.plot(self._t(c["t"]), ratio, "o-", ms=3, lw=1.4, color="C3", label="max penetration / permitted")
        ax.axhline(1.0, color="k", ls="--", lw=1.2, label="permitted |δ'₀|δ̃ (model parameters)")
        ax.set_ylim(0, 1.25 * max(1.0, float(np.nanmax(ratio))))
        self._finish(ax, "−δ / (|δ'₀| δ̃)", "largest penetration vs the permitted one", legend=False)
        ax.legend(fontsize=8, loc="center left", framealpha=0.85)

    def draw_wall_time(self, ax):
        """Where the wall time went (:func:`rundata.wall_time_parts`), with the run's rate and
        energy-balance error: how fast and how accurate, on one panel."""
        s = self.run.summary
        parts = rundata.wall_time_parts(s)
        if not s.get("wall_time_s"):
            self._missing(ax, "no wall time: the run has no summary.json", "where the wall time went")
            return
        wall = s["wall_time_s"]
        names = [k for k, _ in parts][::-1]
        secs = np.array([v for _, v in parts][::-1])
        colours = ["C1" if k.startswith("remesh") else "0.6" if k == "not timed" else "C0" for k in names]
        ax.barh(names, secs, color=colours)
        for y, v in enumerate(secs):
            ax.text(v, y, f" {v:.2f} s ({100 * v / wall:.0f} %)", va="center", fontsize=8)
        ax.set_xlim(0, 1.25 * max(secs.max(), 1e-9))
        ax.set_xlabel("wall time [s] (the largest rank's, per part)")
        err = s.get("energy", {}).get("balance_error_relative")
        rate = s.get("dof_stages_per_s")
        # (at font size 11 the first line ran past the right edge of the figure)
        lines = [f"where the wall time went: {wall:.1f} s on {s.get('ranks', '?')} rank(s)"]
        if rate:
            lines[0] += f", {rate:.3g} DOF·stages/s"
        if err is not None:
            lines.append(f"energy balance error {abs(err):.2g} of the energy put in")
        if s.get("compiling_in_wall_s", 0.0) >= 0.1:  # (within the parts that first called the kernels)
            lines.append(f"{s['compiling_in_wall_s']:.1f} s of it compiled kernels at their first use")
        ax.set_title("\n".join(lines), fontsize=10)
        ax.tick_params(axis="y", labelsize=8)
        ax.grid(alpha=0.3, axis="x")

    # -- files
    SINGLE = {"pressure": ("draw_pressure",), "energy_budget": ("draw_energy",),
              "crack_length": ("draw_lengths",), "contact_modes": ("draw_modes",),
              "opening": ("draw_opening", "draw_penetration"), "wall_time": ("draw_wall_time",)}

    def save(self, out: Path, dpi: int = 110) -> List[Path]:
        plt = pyplot()
        out.mkdir(parents=True, exist_ok=True)
        written = []
        for name, methods in self.SINGLE.items():
            if name == "pressure" and "p_h" not in self.h:
                continue
            if name == "wall_time" and not self.run.summary.get("wall_time_s"):
                continue
            if name not in ("energy_budget", "pressure", "wall_time") and not self.cracks and not (
                    name == "crack_length" and ("network_length" in self.h or "nf_loaded_length" in self.h)):
                continue
            fig, axes = plt.subplots(len(methods), 1, figsize=(6.4, 3.9 * len(methods)), squeeze=False,
                                     sharex=True)
            for m, ax in zip(methods, axes[:, 0]):
                getattr(self, m)(ax)
            fig.suptitle(self.run.name, fontsize=9, x=0.01, ha="left", color="0.4")
            fig.tight_layout()
            path = out / f"{name}.png"
            fig.savefig(path, dpi=dpi)
            plt.close(fig)
            written.append(path)
        fig = plt.figure(figsize=(12.5, 15))
        grid = fig.add_gridspec(4, 2, height_ratios=(1, 1, 1, 0.9))
        for k, m in enumerate(("draw_pressure", "draw_energy", "draw_lengths", "draw_modes", "draw_opening",
                               "draw_penetration")):
            getattr(self, m)(fig.add_subplot(grid[k // 2, k % 2]))
        self.draw_wall_time(fig.add_subplot(grid[3, :]))
        fig.suptitle(f"{self.run.name}: time series", fontsize=13)
        fig.tight_layout()
        path = out / "charts.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        written.append(path)
        return written


def make_charts(source, out=None, max_frames: Optional[int] = None) -> List[Path]:
    """The charts of a run folder; returns the PNG paths (the one-page ``charts.png`` last)."""
    run = load_run(source)
    if not run.history:
        raise FileNotFoundError(f"{run.dir} has no history.csv: the charts need the run's history")
    out = Path(out) if out is not None else run.dir / "figures"
    return Charts(run, max_frames=max_frames).save(out)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hydrofrac.postprocess.charts",
                                     description="Time-series charts of a run from history.csv, summary.json "
                                                 "and the crack frames.")
    parser.add_argument("source", help="output folder of a run (or its .pvd file)")
    parser.add_argument("--out", default=None, help="folder of the PNGs (default RUN/figures)")
    parser.add_argument("--max-frames", type=int, default=None,
                        help="read at most this many crack frames (evenly spread; default all)")
    args = parser.parse_args(argv)
    return rundata.tool_main("charts", lambda: make_charts(args.source, out=args.out, max_frames=args.max_frames))


if __name__ == "__main__":
    sys.exit(main())
