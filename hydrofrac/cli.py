"""The scenarios' command line: the one place argparse lives.

Every scenario script takes the options of :func:`scenario_parser` and its own, and reads
them with :func:`parse`, which handles ``--quick`` one way everywhere (a default given as
``(full, quick)``), never replaces a value the user gave (``--degree 0`` is an error, not the
default), and rejects bad values before any set-up.  :func:`run_options` turns the parsed
options into :class:`~hydrofrac.run.RunOptions`; the physical ones are stored with the
checkpoint, so that a restart with other physics is refused.
"""
from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

from .growth import BRANCH_SPEED
from .material import ROCK
from .run import RunOptions
from .solver import CFL_DEFAULT, MAX_DEGREE, SCHEMES, default_cfl

#: options that do not change the computed result (a restart may change them)
RUN_ONLY = {"out", "t_end", "frames", "restart", "checkpoint_every", "checkpoint_steps", "verbose", "probes"}


def scenario_parser(description: str) -> argparse.ArgumentParser:
    """The command-line options every scenario script accepts."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--quick", action="store_true", help="seconds-long size (used by the tests)")
    p.add_argument("--out", default=None, help="output folder (default results/<scenario>)")
    p.add_argument("--degree", "-p", type=int, default=None, help=f"polynomial degree 1..{MAX_DEGREE}")
    p.add_argument("--t-end", type=float, default=None, help="simulated time [s]")
    p.add_argument("--frames", type=int, default=None, help="number of output frames, evenly spaced in time")
    p.add_argument("--restart", action="store_true", help="continue from the last checkpoint in --out")
    p.add_argument("--checkpoint-every", type=float, default=120.0,
                   help="wall time between checkpoints [s] (default 120; the clock is read every 10 steps)")
    p.add_argument("--checkpoint-steps", type=int, default=None,
                   help="also checkpoint every N steps (default: by wall time only)")
    p.add_argument("--probes", default=None,
                   help="points 'x,y;x,y;...' [m] whose velocity and stress go into probes.csv")
    p.add_argument("--verbose", action="store_true", help="show the form compiler's messages")
    return p


def _pick(value, default, quick):
    """The user's value if given, else the scenario's default ((full, quick) or one value)."""
    if value is not None:
        return value
    if isinstance(default, tuple):
        return default[1] if quick else default[0]
    return default


def parse(parser: argparse.ArgumentParser, argv, name: str, degree, t_end, frames):
    """Parse and validate; fill ``degree``, ``t_end``, ``frames`` and ``out`` (results/<name>;
    ``name`` may be a function of the parsed options) with the scenario's defaults where the
    user gave none.  Exits with argparse's message (status 2)
    on a bad value, before any set-up."""
    args = parser.parse_args(argv)
    args.degree = _pick(args.degree, degree, args.quick)
    args.t_end = _pick(args.t_end, t_end, args.quick)
    args.frames = _pick(args.frames, frames, args.quick)
    if not 1 <= args.degree <= MAX_DEGREE:
        parser.error(f"--degree must be in 1..{MAX_DEGREE}; got {args.degree}")
    if not (math.isfinite(args.t_end) and args.t_end > 0):
        parser.error(f"--t-end must be a positive time in seconds; got {args.t_end}")
    if args.frames < 1:
        parser.error(f"--frames must be >= 1; got {args.frames}")
    if not (math.isfinite(args.checkpoint_every) and args.checkpoint_every > 0):
        parser.error(f"--checkpoint-every must be > 0 s; got {args.checkpoint_every}")
    if args.checkpoint_steps is not None and args.checkpoint_steps < 1:
        parser.error(f"--checkpoint-steps must be >= 1; got {args.checkpoint_steps}")
    if args.probes is not None:
        from .probes import parse_points
        try:
            args.probes = parse_points(args.probes).tolist()
        except ValueError as err:
            parser.error(f"--probes: {err}")
    if args.out is None:
        args.out = f"results/{name(args) if callable(name) else name}"
    check_out(parser, args.out)
    from . import compat
    compat.quiet_form_compiler(not args.verbose)
    return args


def check_out(parser, out: str):
    """The output folder is a folder we can write (or can be made), or exit with the fix."""
    if not str(out).strip():
        parser.error("--out must name a folder; got an empty string")
    p = Path(out)
    if p.exists() and not p.is_dir():
        parser.error(f"--out {out} is a file, not a folder; give a folder")
    q = p
    while not q.exists():
        q = q.parent
    if not q.is_dir() or not os.access(q, os.W_OK | os.X_OK):
        parser.error(f"--out {out}: cannot write in {q}; give a folder you can write")


def run_options(args, history_every: int = 1) -> RunOptions:
    """:class:`~hydrofrac.run.RunOptions` of parsed scenario options."""
    params = {k: v for k, v in sorted(vars(args).items()) if k not in RUN_ONLY}
    return RunOptions(t_end=args.t_end, out=args.out, frames=args.frames, restart=args.restart,
                      checkpoint_wall=args.checkpoint_every, checkpoint_steps=args.checkpoint_steps,
                      history_every=history_every, params=params, probes=args.probes)


# ----------------------------------------------------------------------------- time scheme
def add_time_scheme_arguments(parser, cracks=True):
    """``--scheme`` and ``--cfl``: the explicit scheme and its CFL constant (the measured
    trade-off on the crack runs: docs/benchmarks.md, "The scheme of a crack run" and "ADER with
    crack interfaces")."""
    ader = ("ader: one predictor and one corrector per step, the cracks' flux at the stages of a Runge-Kutta "
            "scheme of its order, docs/benchmarks.md" if cracks else
            "ader: the one-step scheme for the bulk, docs/benchmarks.md")
    parser.add_argument("--scheme", choices=SCHEMES, default="rk4",
                        help=f"time scheme (default rk4; lsrk54: 5-stage steps up to 1.64x longer, 10/7 in growth "
                             f"runs, whose steps fit the check interval; {ader})")
    parser.add_argument("--cfl", type=float, default=None,
                        help=f"CFL constant C of dt = C h_min / ((2p + 1) c_d) (default: the scheme's documented "
                             f"stable constant, {', '.join(f'{k} {v}' for k, v in CFL_DEFAULT.items())}, ader by "
                             f"degree; less for a study of dt)")


def check_time_scheme_arguments(parser, args):
    """Reject a CFL constant above the scheme's documented stable one, before any meshing (a
    scheme the cracks cannot use is the problem description's to refuse:
    :class:`hydrofrac.wellbore.Wellbore`)."""
    if args.cfl is not None:
        limit = default_cfl(args.scheme, args.degree)
        if not (math.isfinite(args.cfl) and 0 < args.cfl <= limit):
            parser.error(f"--cfl must be in (0, {limit}] for --scheme {args.scheme} (its documented stable "
                         f"constant, calibrated in docs/verification.md); got {args.cfl}")


# ----------------------------------------------------------------------------- free growth
def delta0_type(text):
    """``--delta0``: a maximum normalised penetration δ'₀ < 0, or ``resolved`` (None: resolved
    in time from the step and the closing speed, :class:`hydrofrac.interface.ContactParams`)."""
    if text == "resolved":
        return None
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number < 0 or 'resolved'; got {text!r}") from None
    if not value < 0:
        raise argparse.ArgumentTypeError(f"the maximum normalised penetration must be < 0; got {value}")
    return value


def add_pressure_factor_argument(parser, default="connected", why=""):
    """``--pressure-factor connected|local`` of the wellbore scenarios (docs/model.md, "The
    pressure factor through connected apertures"); ``why``: the scenario's reason for its
    default, for the help text."""
    parser.add_argument("--pressure-factor", choices=("connected", "local"), default=default,
                        help="'connected': a crack vertex carries no more load than the narrowest opening on the "
                             "widest path from the wellbore to it allows; 'local': eq. (15) at each vertex alone, "
                             f"so an open crack end takes the load through a closed part (default {default}{why})")


def add_growth_arguments(parser, natural_tips=False, branch_speed=math.inf, nucleation_cap=0, remesh="patch"):
    """The free-growth options shared by the wellbore scenarios (intersection, re-fracture):
    ``--growth`` (the default) / ``--premeshed`` and the criterion's parameters, in
    crack-facet sizes h; the network's events default to the scenario's ``natural_tips``,
    ``branch_speed`` and ``nucleation_cap`` (one value, or (full size, ``--quick``)), the remesh
    to its ``remesh`` ("full" or "patch"; with ``--adapt`` always "full", since adaptive meshes
    change the size field everywhere: :func:`check_growth_arguments` resolves it).  (One add_argument per option, each with its own help: the repeated
    shape is argparse's, kept on purpose for the readable help texts.)"""
    g = parser.add_mutually_exclusive_group()
    g.add_argument("--growth", dest="growth", action="store_true", default=True,
                   help="free crack growth from the perforation tips with Gmsh remeshing (default)")
    g.add_argument("--premeshed", dest="growth", action="store_false",
                   help="grow along pre-meshed radial potential paths instead (no remeshing)")
    parser.add_argument("--growth-r", type=float, default=4.0,
                        help="sampling distance of the growth criterion ahead of a tip, in crack facet sizes h "
                             "(default 4)")
    parser.add_argument("--growth-beta", type=float, default=0.0,
                        help="shear factor beta of the sampled growth criterion (default 0: the largest tensile "
                             "normal traction; 1 = the damage law's, which follows the shear of the compressive "
                             "pressure waves around the wellbore: see docs/studies/growth.md)")
    parser.add_argument("--growth-direction", choices=("sampled", "cod"), default="cod",
                        help="'cod' (default) takes the sampled onset and the angle of the singular near-tip "
                             "field, K_II/K_I from the crack's slip and opening within r of the tip; 'sampled' "
                             "grows towards the maximum of the sampled criterion (kinks: docs/studies/growth.md)")
    parser.add_argument("--growth-cod-window", type=float, default=None,
                        help="with --growth-direction cod: distance behind the tip over which opening and slip "
                             "are correlated, in facet sizes h (default: the sampling distance r)")
    parser.add_argument("--growth-cod-relax", type=float, default=0.5,
                        help="with --growth-direction cod: fraction of the near-tip angle taken per extension "
                             "(default 0.5; 1 zigzags beyond ~1 m in the full-size intersection: "
                             "docs/studies/growth.md)")
    parser.add_argument("--growth-da", type=float, default=2.0,
                        help="length of a growth step, in crack facet sizes h (default 2)")
    parser.add_argument("--growth-natural-tips", action=argparse.BooleanOptionalAction, default=natural_tips,
                        help="natural fractures grow from their ends too, by the same criterion "
                             f"(default {'on' if natural_tips else 'off'})")
    parser.add_argument("--growth-max-speed", type=float, default=ROCK.cR,
                        help=f"largest tip speed [m/s] (default the Rayleigh speed c_R = {ROCK.cR:.0f}, the limit of a "
                             "tensile crack's speed; inf: none, tips then run as fast as the check interval lets "
                             "them, measured up to 5900 m/s; docs/studies/growth.md)")
    parser.add_argument("--growth-branch-speed", type=float, default=branch_speed,
                        help="a tip this fast [m/s] whose criterion has two separated maxima above the onset "
                             f"branches (default {branch_speed:.0f}; inf: no branching; the model's value is "
                             f"0.5 c_R = {BRANCH_SPEED:.0f}, docs/model.md §6 and docs/studies/growth.md)")
    by_size = isinstance(nucleation_cap, tuple)  # (full size, --quick): resolved by resolve_by_size
    parser.add_argument("--growth-nucleation-cap", type=int, default=None if by_size else nucleation_cap,
                        help="at most this many microcracks nucleate where the bulk reaches the strength "
                             f"(default {f'{nucleation_cap[0]}, --quick {nucleation_cap[1]}' if by_size else nucleation_cap}"
                             "; 0: none)")
    parser.set_defaults(_nucleation_by_size=list(nucleation_cap) if by_size else None)  # a list: as a checkpoint keeps it
    parser.add_argument("--growth-max-radius", type=float, default=None,
                        help="tips stop at this distance from the wellbore centre [m] (default: only the outer "
                             "boundary stops them)")
    if remesh not in ("full", "patch"):
        raise ValueError(f"remesh must be 'full' or 'patch'; got {remesh!r}")
    parser.add_argument("--growth-remesh", choices=("full", "patch"), default=None,
                        help="after an extension, mesh the whole domain again (full) or only a patch around the "
                             "new segments, keeping the rest of the mesh (patch; docs/benchmarks.md, \"Remeshing: "
                             f"local patches\"); default {remesh}, and full with --adapt")
    parser.set_defaults(_remesh_default=remesh)
    parser.add_argument("--growth-patch-radius", type=float, default=6.0,
                        help="with --growth-remesh patch: the triangles within this distance of a new segment's "
                             "ends, in facet sizes h, and the too-coarse ones next to them, are meshed again "
                             "(default 6)")


#: the growth options' valid values: (option, test, what a valid value is); None passes
_GROWTH_CHECKS = (
    ("growth_r", lambda v: v > 0, "> 0 (a distance in facet sizes)"),
    ("growth_da", lambda v: v > 0, "> 0 (a length in facet sizes)"),
    ("growth_beta", lambda v: v >= 0, ">= 0"),
    ("growth_cod_relax", lambda v: 0 < v <= 1, "in (0, 1]"),
    ("growth_max_radius", lambda v: v > 0, "> 0 m"),
    ("growth_cod_window", lambda v: v > 0, "> 0 (a distance in facet sizes)"),
    ("growth_max_speed", lambda v: v > 0, "> 0 m/s"),
    ("growth_nucleation_cap", lambda v: v >= 0, ">= 0"),
    ("growth_branch_speed", lambda v: v > 0, "> 0 m/s (inf: no branching)"),
    ("growth_patch_radius", lambda v: v > 0, "> 0 (a distance in facet sizes)"),
)


def add_adapt_arguments(parser):
    """``--adapt H_FINE`` and ``--adapt-tol`` (docs/model.md, "Adaptive meshes")."""
    from .wellbore import ADAPT_TOL
    parser.add_argument("--adapt", type=float, default=None, metavar="H_FINE",
                        help="adaptive meshes with this fine size [m] (docs/model.md, 'Adaptive meshes'): "
                             "the cracks and growing tips at it, the bulk fine where it jumps and coarse (to 1 m) "
                             "elsewhere (full remeshes: not with --growth-remesh patch)")
    parser.add_argument("--adapt-tol", type=float, default=ADAPT_TOL,
                        help=f"the bulk jump that asks for refinement, relative to the peak load (default {ADAPT_TOL})")


def check_adapt_arguments(parser, args):
    """Reject bad adaptive-mesh options before any meshing (exit 2, naming the option), and
    ``--adapt-tol`` without ``--adapt`` (it would be ignored)."""
    if args.adapt is None and _given(parser, args, "adapt_tol"):
        parser.error("--adapt-tol sets the refinement threshold of adaptive meshes: give --adapt H_FINE too, "
                     "or drop --adapt-tol")
    if args.adapt is not None and not 0 < args.adapt < 1.0:
        parser.error(f"--adapt must be a size in (0, 1) m; got {args.adapt}")
    if not args.adapt_tol > 0:
        parser.error(f"--adapt-tol must be > 0; got {args.adapt_tol}")


def add_mesh_size_arguments(parser, h_crack, h_far):
    """``--h-crack`` and ``--h-far`` [m] (a wellbore scenario's mesh sizes; ``h_crack`` and
    ``h_far``: their defaults as text for the help, e.g. "0.04, --quick 0.05")."""
    parser.add_argument("--h-crack", type=float, default=None,
                        help=f"mesh size at the cracks [m] (default {h_crack}; Δa and r scale with it)")
    parser.add_argument("--h-far", type=float, default=None,
                        help=f"mesh size far from the cracks [m] (default {h_far})")


def check_mesh_size_arguments(parser, args):
    """Reject a mesh size outside (0, 1) m before any meshing (exit 2, naming the option)."""
    for key in ("h_crack", "h_far"):
        v = getattr(args, key)
        if v is not None and not 0 < v < 1.0:
            parser.error(f"--{key.replace('_', '-')} must be in (0, 1) m; got {v}")


def _given(parser, args, prefix):
    """The options starting with ``prefix`` (as dest names) whose values are not the parser's
    defaults: the ones the user gave (or gave their default value, which changes nothing)."""
    return sorted(k for k in vars(args) if k.startswith(prefix) and getattr(args, k) != parser.get_default(k))


def check_growth_arguments(parser, args):
    """Reject bad growth options before any meshing (argparse's error: exit 2, with the fix);
    a default given by size takes the run's size here.  A growth option with ``--premeshed``,
    which grows nothing, is an error too, not ignored."""
    if not args.growth:
        given = _given(parser, args, "growth_")
        if given:
            parser.error(f"{', '.join('--' + k.replace('_', '-') for k in given)}: only free growth (--growth) uses "
                         f"{'this option' if len(given) == 1 else 'these options'}; drop "
                         f"{'it' if len(given) == 1 else 'them'} or drop --premeshed")
    by_size = getattr(args, "_nucleation_by_size", None)
    if by_size is not None and args.growth_nucleation_cap is None:
        args.growth_nucleation_cap = by_size[1] if args.quick else by_size[0]
    if args.growth_remesh is None:  # the scenario's default; adaptive meshes remesh the whole domain
        args.growth_remesh = "full" if getattr(args, "adapt", None) is not None else args._remesh_default
    if args.growth:  # (an option of one growth mode given with the other)
        for name, needs, mode in (("growth_cod_window", "growth_direction", "cod"),
                                  ("growth_cod_relax", "growth_direction", "cod"),
                                  ("growth_patch_radius", "growth_remesh", "patch")):
            if _given(parser, args, name) and getattr(args, needs) != mode:
                why = " (adaptive meshes remesh the whole domain)" if getattr(args, "adapt", None) is not None else ""
                parser.error(f"--{name.replace('_', '-')} acts only with --{needs.replace('_', '-')} {mode}; "
                             f"this run has --{needs.replace('_', '-')} {getattr(args, needs)}{why}: drop one of them")
    for name, ok, valid in _GROWTH_CHECKS:
        v = getattr(args, name)
        if v is not None and not ok(v):
            parser.error(f"--{name.replace('_', '-')} must be {valid}; got {v}")
