"""A/B: a scenario run by this working tree and by an earlier revision of the code, alternating,
in one series (docs/benchmarks.md, "A/B against an earlier revision").

This machine's speed drifts by up to 40 % between runs minutes apart, so a speed-up is only
measured side by side: the two codes take turns, round after round, and each ratio is taken
within its round.  The order turns every round (the base first in odd rounds, last in even
ones), and the table gives the geometric mean of the rounds' ratios: with the same code on
both sides, a series in a fixed order gave 0.93–0.94× in each of three rounds, and one in
turned order 1.07, 1.02, 1.09 and 0.87× (mean 1.01×).  Differences under about 10 % are not
resolved by one series (docs/benchmarks.md, "A/B against an earlier revision").  The earlier revision runs from a git worktree of its own, with its
``forms/``, ``meshes/`` and ``postprocess/`` linked into its ``hydrofrac/`` as its
``pyproject.toml`` maps them, so that it imports none of this tree's code (checked before any
run: every package must come from the worktree).  Each code runs once with ``--warmup``'s
arguments first, so that numba's and the C kernels' compiles stay out of the series.

    python -m hydrofrac.postprocess.ab scenarios/refracture.py --base ab93a21 \\
        --args "--frames 40" --variant "rk4=--scheme rk4" --variant "ader=--scheme ader"

Every variant (``LABEL=ARGS``, default one, ``head``, with no arguments) runs this tree with
``--args`` and its own arguments; the base runs the revision with ``--args`` and
``--base-args``.  Writes ``ab.png`` (each run's wall time as stepping and remeshing, round
by round, with the ratios), ``ab.csv`` (one row per run: the summary's speed, work, remeshing, time split
and scalar ``accuracy`` entries) and ``ab.md`` (per variant: its wall times, the base's wall
time over its own in each round, each part of the time split with the same ratio, and each
accuracy entry against the base's) into
``--out``; each run's output folder is kept under it.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("hydrofrac", "hydrofrac.forms", "hydrofrac.meshes", "hydrofrac.postprocess")
#: the summary's entries a row gives (missing in an old summary: empty)
#: the label of the earlier revision's runs
BASE = "base"
COLUMNS = ("wall_time_s", "steps", "dt", "cells", "dofs", "scheme", "dof_stages_per_s",
           "compiling_in_wall_s")


class Error(Exception):
    """What to change, before any run."""


def _git(*args, cwd=ROOT):
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True)


def resolve(rev):
    """The commit of ``rev`` in this repository."""
    r = _git("rev-parse", "--verify", "--quiet", f"{rev}^{{commit}}")
    if r.returncode:
        raise Error(f"--base {rev!r} is not a commit of this repository ({ROOT}); give a commit, tag or "
                    "branch that `git log` shows")
    return r.stdout.strip()


def worktree(commit, where):
    """A detached worktree of ``commit`` at ``where``, its subpackages linked into its
    ``hydrofrac/`` as its ``pyproject.toml``'s ``[tool.setuptools.package-dir]`` maps them."""
    r = _git("worktree", "add", "--detach", str(where), commit)
    if r.returncode:
        raise Error(f"git worktree add {where} {commit} failed: {r.stderr.strip()}")
    meta = tomllib.loads((where / "pyproject.toml").read_text())
    dirs = meta.get("tool", {}).get("setuptools", {}).get("package-dir", {})
    for pkg, folder in dirs.items():
        parts = pkg.split(".")
        if len(parts) != 2 or parts[0] != "hydrofrac" or folder == pkg.replace(".", "/"):
            continue
        link = where / "hydrofrac" / parts[1]
        if not link.exists():
            link.symlink_to(Path("..") / folder)
    return where


def remove_worktree(where):
    _git("worktree", "remove", "--force", str(where))
    shutil.rmtree(where, ignore_errors=True)
    _git("worktree", "prune")


def environment(code):
    """The environment of a run of ``code`` (a folder holding ``hydrofrac/``)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(code)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    env.setdefault("OMPI_ALLOW_RUN_AS_ROOT", "1")
    env.setdefault("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
    return env


def check_imports(code, python):
    """Every package of :data:`PACKAGES` that a run of ``code`` imports must lie in ``code``:
    otherwise the run would mix the two codes (an editable install of this tree maps its
    subpackages to this tree's folders)."""
    probe = "import importlib, json; print(json.dumps({p: importlib.import_module(p).__file__ for p in %r}))" % (
        PACKAGES,)
    r = subprocess.run([python, "-c", probe], cwd=code, env=environment(code), capture_output=True, text=True)
    if r.returncode:
        raise Error(f"the code in {code} does not import: {r.stderr.strip()[-400:]}")
    files = json.loads(r.stdout.strip().splitlines()[-1])
    wrong = {p: f for p, f in files.items() if not Path(f).resolve().is_relative_to(Path(code).resolve())}
    if wrong:
        raise Error(f"the run of {code} would import {wrong} from outside it; link those packages into "
                    f"{code}/hydrofrac as its pyproject.toml maps them")
    return files


def run_one(code, script, args, out, ranks, python, mpirun):
    """One run of ``script`` with ``args`` from ``code`` on ``ranks`` ranks, its output in ``out``;
    its summary (raises with the log's tail if it failed)."""
    cmd = ([] if ranks == 1 else shlex.split(mpirun) + ["-n", str(ranks)]) + [python, script, *args, "--out", str(out)]
    log = Path(str(out) + ".log")
    shutil.rmtree(out, ignore_errors=True)  # (a summary left by an earlier series must not pass for this run's)
    with open(log, "w") as f:
        r = subprocess.run(cmd, cwd=code, env=environment(code), stdout=f, stderr=subprocess.STDOUT)
    summary = Path(out) / "summary.json"
    if r.returncode or not summary.exists():
        tail = log.read_text()[-1500:]
        written = "written" if summary.exists() else "missing"
        raise RuntimeError(f"{' '.join(cmd)} (in {code}) failed (exit {r.returncode}, summary {written}); "
                           f"its log {log} ends:\n{tail}")
    return json.loads(summary.read_text())


def row(summary):
    """The CSV row of a run's summary: :data:`COLUMNS`, the remeshing, the stepping (the wall time
    less the remeshing), the time split's parts and the scalar accuracy entries."""
    out = {k: summary.get(k, "") for k in COLUMNS}
    rem = summary.get("remeshing") or {}
    out["remeshes"] = rem.get("remeshes", "")
    out["remeshing_s"] = rem.get("wall_s", "")
    out["remeshing_share"] = rem.get("share", "")
    out["time.stepping (wall - remeshing)"] = summary["wall_time_s"] - (rem.get("wall_s") or 0.0)
    for k, v in (summary.get("time_split_s") or {}).items():
        out["time." + k] = v
    for k, v in (summary.get("accuracy") or {}).items():
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            out["accuracy." + k] = v
    return out


def _fmt(v):
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _span(vals):
    lo, hi = min(vals), max(vals)
    return _fmt(lo) if lo == hi else f"{_fmt(lo)}–{_fmt(hi)}"


def _against(pairs):
    """How a label's values compare with the base's of the same rounds: "(= base)" when every
    one is the same number, else the largest relative difference."""
    both = [(v, b) for v, b in pairs if v != "" and b != ""]
    if not both:
        return "(base: —)"
    if all(v == b or (v != v and b != b) for v, b in both):
        return "(= base)"
    rel = max(abs(v - b) / max(abs(b), 1e-300) for v, b in both)
    return f"(Δ {rel:.1e})"


def _series(rows):
    """(labels in order of appearance, rounds, {(label, round): row}) of a series' rows."""
    return (list(dict.fromkeys(r["label"] for r in rows)), sorted({r["round"] for r in rows}),
            {(r["label"], r["round"]): r for r in rows})


def report(rows, base_label=BASE):
    """The Markdown tables of the series: per label its wall times and work, with the base's wall
    time over its own in each round (the speed-up, round by round); each part of the time split
    (and the stepping) with the same ratios; each accuracy entry the base writes, of each label
    against the base's (equal, or the largest relative difference); the entries it does not."""
    labels, rounds, by = _series(rows)
    lines = ["| | wall [s] | base / this, round by round | DOF·stages/s | steps | remeshes (share) |",
             "|---|---|---|---|---|---|"]
    for lab in labels:
        rs = [by[(lab, k)] for k in rounds if (lab, k) in by]
        ratios = [by[(base_label, k)]["wall_time_s"] / by[(lab, k)]["wall_time_s"] for k in rounds
                  if (lab, k) in by and (base_label, k) in by]
        share = [r["remeshing_share"] for r in rs if r["remeshing_share"] != ""]
        walls = ", ".join("%.2f" % r["wall_time_s"] for r in rs)
        speedups = "—" if lab == base_label else ", ".join("%.2f×" % x for x in ratios)
        if lab != base_label and len(ratios) > 1:
            speedups += "; geometric mean %.2f×" % math.exp(sum(math.log(x) for x in ratios) / len(ratios))
        lines.append(f"| {lab} | {walls} | {speedups} | "
                     f"{_span([r['dof_stages_per_s'] for r in rs])} | {_span([r['steps'] for r in rs])} | "
                     f"{_span([r['remeshes'] for r in rs]) if rs[0]['remeshes'] != '' else '—'}"
                     f"{' (' + _span([round(100 * s) for s in share]) + ' %)' if share else ''} |")
    parts = sorted({k for r in rows for k in r if k.startswith("time.")}, key=lambda k: -by[(base_label, rounds[0])].get(k, 0.0))
    if parts:
        lines += ["", "| time split [s] (base / this, round by round) | " + " | ".join(labels) + " |",
                  "|---" * (len(labels) + 1) + "|"]
        for k in parts:
            cells = []
            for lab in labels:
                rs = [j for j in rounds if (lab, j) in by and by[(lab, j)].get(k, "") != ""]
                cell = _span([by[(lab, j)][k] for j in rs]) if rs else "—"
                if lab != base_label and rs:
                    ratios = [by[(base_label, j)][k] / by[(lab, j)][k] for j in rs
                              if by.get((base_label, j), {}).get(k, "") != "" and by[(lab, j)][k] > 0]
                    cell += f" ({_span([round(x, 2) for x in ratios])}×)" if ratios else ""
                cells.append(cell)
            lines.append(f"| {k[len('time.'):]} | " + " | ".join(cells) + " |")
    keys = sorted({k for r in rows for k in r if k.startswith("accuracy.")})
    base_keys = {k for r in rows if r["label"] == base_label for k in r if r[k] != ""}
    only = [k for k in keys if k not in base_keys]
    keys = [k for k in keys if k in base_keys]
    if keys:
        lines += ["", "| accuracy | " + " | ".join(labels) + " |", "|---" * (len(labels) + 1) + "|"]
        for k in keys:
            cells = []
            for lab in labels:
                pairs = [(by[(lab, j)].get(k, ""), by.get((base_label, j), {}).get(k, "")) for j in rounds
                         if (lab, j) in by]
                vals = [v for v, _ in pairs if v != ""]
                cell = _span(vals) if vals else "—"
                if lab != base_label and vals:
                    cell += " " + _against(pairs)
                cells.append(cell)
            lines.append(f"| {k[len('accuracy.'):]} | " + " | ".join(cells) + " |")
    if only:
        lines += ["", "Accuracy entries the base does not write: " + ", ".join(k[len("accuracy."):] for k in only) + "."]
    return "\n".join(lines) + "\n"


def parse_variants(items):
    out = []
    for item in items or ["head="]:
        label, sep, args = item.partition("=")
        if not sep or not label or label == BASE:
            raise Error(f"--variant {item!r}: give LABEL=ARGS with a label other than {BASE!r} (ARGS may be empty)")
        out.append((label, shlex.split(args)))
    if len({lab for lab, _ in out}) != len(out):
        raise Error("--variant labels must differ")
    return out


#: the options whose value is a command line of its own, which may begin with '-'
_COMMAND_LINES = ("--args", "--base-args", "--warmup")


def _glued(argv):
    """``argv`` with each of :data:`_COMMAND_LINES` glued to its value (``--args --quick`` as
    ``--args=--quick``): argparse would take a value that begins with '-' for an option."""
    out, i = [], 0
    while i < len(argv):
        if argv[i] in _COMMAND_LINES and i + 1 < len(argv):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("script", help="the scenario script, relative to the repository root (e.g. scenarios/refracture.py)")
    p.add_argument("--base", required=True, help="the earlier revision (commit, tag or branch)")
    p.add_argument("--args", default="", help="arguments of every run")
    p.add_argument("--base-args", default="", help="the base's own arguments, after --args")
    p.add_argument("--variant", action="append", metavar="LABEL=ARGS",
                   help="a run of this tree with its own arguments after --args (repeatable; default 'head=')")
    p.add_argument("--rounds", type=int, default=2, help="rounds of the series (each: the base and every variant, the order turned every round)")
    p.add_argument("--ranks", type=int, default=2)
    p.add_argument("--warmup", default="--quick",
                   help="arguments of each code's warm-up run before the series (default --quick; 'none': no warm-up)")
    p.add_argument("--out", default="results/ab")
    p.add_argument("--mpirun", default="mpirun --oversubscribe")
    args = p.parse_args(_glued(sys.argv[1:] if argv is None else list(argv)))
    try:
        variants = parse_variants(args.variant)
        if args.rounds < 1 or args.ranks < 1:
            raise Error(f"--rounds and --ranks must be at least 1; got {args.rounds} and {args.ranks}")
        if not (ROOT / args.script).is_file():
            raise Error(f"no scenario script {args.script!r} in {ROOT}; give its path from the repository root")
        if args.ranks > 1 and shutil.which(shlex.split(args.mpirun)[0]) is None:
            raise Error(f"{args.mpirun!r} is not on the PATH; install openmpi-bin or run with --ranks 1")
        commit = resolve(args.base)
    except Error as e:
        p.error(str(e))
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    where = Path(tempfile.mkdtemp(prefix="hydrofrac-ab-")) / "base"
    try:
        try:
            worktree(commit, where)
            if not (where / args.script).is_file():
                raise Error(f"the base {args.base} ({commit[:10]}) has no {args.script}")
            files = {BASE: check_imports(where, sys.executable), "head": check_imports(ROOT, sys.executable)}
        except Error as e:
            p.error(str(e))
        print(f"[ab] base {args.base} = {commit[:10]} in {where}; this tree {ROOT}", flush=True)
        for name, f in files.items():
            print(f"[ab]   {name} imports hydrofrac from {Path(f['hydrofrac']).parent}", flush=True)
        common = shlex.split(args.args)
        runs = [(BASE, where, common + shlex.split(args.base_args))] + [(lab, ROOT, common + a) for lab, a in variants]
        if args.warmup != "none":  # (each run's own arguments, so that its scheme's kernels are compiled)
            for label, code, a in runs:
                print(f"[ab] warm-up of {label}: {' '.join(a + shlex.split(args.warmup))}", flush=True)
                run_one(code, args.script, a + shlex.split(args.warmup), out / f"warmup_{label}", args.ranks,
                        sys.executable, args.mpirun)
        rows = []
        for k in range(1, args.rounds + 1):
            for label, code, a in (runs if k % 2 else runs[::-1]):  # (the order turns: see the docstring)
                s = run_one(code, args.script, a, out / f"{label}_{k}", args.ranks, sys.executable, args.mpirun)
                rows.append({"round": k, "label": label, "args": " ".join(a), **row(s)})
                print(f"[ab] round {k} {label}: {s['wall_time_s']:.2f} s", flush=True)
                _write(out, rows)
        table = report(rows)
        header = (f"{args.script}, {args.ranks} rank(s), {args.rounds} round(s); base {args.base} ({commit[:10]}) "
                  f"with `{' '.join(runs[0][2])}`; " + "; ".join(f"{lab} with `{' '.join(a)}`" for lab, _, a in runs[1:]))
        (out / "ab.md").write_text(header + "\n\n" + table)
        chart(rows, out / "ab.png", title=f"{args.script}: {args.ranks} rank(s), base {args.base}")
        print(header + "\n\n" + table, flush=True)
    finally:
        remove_worktree(where)
        shutil.rmtree(where.parent, ignore_errors=True)
    return rows


def chart(rows, path, title="", base_label=BASE):
    """``path`` (PNG): each run's wall time as a bar of its stepping and its remeshing, the runs
    of a round side by side, each labelled with the base's wall time over its own."""
    from hydrofrac.postprocess.charts import pyplot
    plt = pyplot()
    labels, rounds, by = _series(rows)
    fig, ax = plt.subplots(figsize=(1.6 + 1.1 * len(labels) * len(rounds), 4.0))
    width = 0.8 / len(labels)
    for i, lab in enumerate(labels):
        xs, step, rem, speed = [], [], [], []
        for k in rounds:
            r = by.get((lab, k))
            if r is None:
                continue
            xs.append(k + (i - (len(labels) - 1) / 2) * width)
            rem.append(r["remeshing_s"] or 0.0)
            step.append(r["wall_time_s"] - rem[-1])
            b = by.get((base_label, k))
            speed.append("" if lab == base_label or b is None else f"{b['wall_time_s'] / r['wall_time_s']:.2f}×")
        bars = ax.bar(xs, step, width * 0.92, label=f"{lab}: stepping", color=f"C{i}")
        ax.bar(xs, rem, width * 0.92, bottom=step, label=f"{lab}: remeshing", color=f"C{i}", alpha=0.45, hatch="//")
        for bar, s, r_ in zip(bars, speed, rem):
            if s:
                ax.text(bar.get_x() + bar.get_width() / 2, bar.get_height() + r_, s, ha="center", va="bottom", fontsize=8)
    ax.set_xticks(rounds, [f"round {k}" for k in rounds])
    ax.set_ylabel("wall time [s]")
    ax.set_title(title + "\n(the base's wall time over each run's, within its round)", fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _write(out, rows):
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(out / "ab.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)


if __name__ == "__main__":
    main()
