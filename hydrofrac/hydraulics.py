"""Hydraulic load on cracks: connectivity, the aperture-based pressure factor f_p
and the separation traction S of loaded cracks (model.md §5, eqs. 14-16).

* A crack facet joins the *network* when it is debonded: its mean damage
  reaches ``threshold`` (default 0.99 [our choice]; D -> 1 only asymptotically
  under the rate law).  Source facets (perforations) always belong to it.
* Network facets that share a vertex are connected (connected components of the
  facet-vertex graph of all ranks); a component is *loaded* if it contains a source facet.
* Pressure factor at a crack vertex P: ``f_p(P) = clip(delta_P,max / (delta_bar' delta~), 0, 1)``
  with ``delta_P,max`` the largest opening at P of the loaded facets meeting at P
  (the opening at a facet end is its nearest Gauss point's); interpolated
  linearly along each facet.  Source facets are always fully loaded (f_p = 1):
  the perforations are connected to the wellbore [our choice].
  Unregularised mode: f_p = 1 on every facet of a loaded component.
* Separation traction of loaded facets: ``S^1 = -[f_p p_h(t) + (1 - f_p) <-s_B^1>]``,
  ``S^2 = 0``; unloaded facets: S = 0.

* Fluid volume (optional, ``HydraulicParams.volume``): the fluid pumped in by time t, V(t),
  fills the loaded facets from the sources outward, in the order of their distance along
  the network, each up to its aperture (at least δ̄'δ̃); beyond the fluid's front a crack
  is dry, S = 0 as on an unloaded crack (:func:`fluid_fill`, docs/model.md, "A finite fluid
  volume").  Without it the fluid supply is unlimited (the paper's pressure control).

Connectivity and f_p are updated once per time step from the current state
(they lag the Runge-Kutta stages by at most one step).
"""
from __future__ import annotations

import heapq
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from mpi4py import MPI

from . import compat
from ._jit import njit
from . import riemann as rm
from .boundary import PiecewiseLinear


def components(edges_vertices: np.ndarray, active: np.ndarray, index=None) -> np.ndarray:
    """Component label per facet of a crack network.

    edges_vertices : (m, 2) vertex ids of each facet (any integer ids)
    active : (m,) bool, facets in the network; inactive facets get -1
    index : :func:`vertex_index` of ``edges_vertices``, if known (a network's, once per mesh):
        then the graph is the vertices' with the active facets as edges, and a facet's label its
        first vertex's (other numbers, the same components)

    Active facets sharing a vertex are joined: the connected components of the facet-vertex
    graph (``scipy.sparse.csgraph.connected_components``, compiled).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    m = edges_vertices.shape[0]
    labels = np.full(m, -1, dtype=np.int64)
    idx = np.flatnonzero(active)
    if not idx.size:
        return labels
    if index is not None:
        ev, nv = index
        a = ev[idx]
        _, lab = connected_components(coo_matrix((np.ones(idx.size), (a[:, 0], a[:, 1])), shape=(nv, nv)),
                                      directed=False)
        labels[idx] = lab[a[:, 0]]
        return labels
    uniq, inv = np.unique(np.asarray(edges_vertices)[idx].reshape(-1), return_inverse=True)
    n = idx.size + uniq.size  # nodes: the active facets, then their vertices
    rows = np.repeat(np.arange(idx.size), 2)
    G = coo_matrix((np.ones(rows.size), (rows, idx.size + inv)), shape=(n, n))
    _, lab = connected_components(G, directed=False)
    labels[idx] = lab[:idx.size]
    return labels


def loaded_facets(edges_vertices, active, source, index=None) -> np.ndarray:
    """(m,) bool: active facets whose component contains an active source facet (``index``:
    as :func:`components`)."""
    roots = components(edges_vertices, active, index)
    src_roots = np.unique(roots[active & source])
    return active & np.isin(roots, src_roots)


def vertex_index(edges_vertices):
    """((m, 2) compact vertex number of each facet end, vertex count) of a facet list with any
    integer vertex ids: the facet-vertex graph the pressure factor runs on (a network's is
    computed once per mesh, :class:`Hydraulics`)."""
    ev = np.asarray(edges_vertices).reshape(-1)
    uniq, inv = np.unique(ev, return_inverse=True)
    return inv.reshape(-1, 2).astype(np.int64), int(uniq.size)


def pressure_factor_vertices(edges_vertices, loaded, opening_ends, scale, source=None, index=None):
    """f_p per facet end, (m, 2): from the largest opening of the loaded facets at each vertex.

    opening_ends : (m, 2) opening at each facet end; scale : delta_bar' * delta~ (per facet, (m,))
    source : (m,) bool, the source facets; given, the factors are *connected*
    (:func:`connected_factor`): a facet end carries no more than the narrowest opening on the
    widest path from a source to it (docs/model.md, "The pressure factor through connected
    apertures").  None: eq. (15) at each vertex alone.
    index : :func:`vertex_index` of ``edges_vertices``, if known.  One compiled pass.
    """
    ev, nv = vertex_index(edges_vertices) if index is None else index
    m = ev.shape[0]
    connected = source is not None
    src = np.asarray(source, dtype=np.bool_) if connected else np.zeros(m, dtype=np.bool_)
    return _pressure_factor(ev, nv, np.asarray(loaded, dtype=np.bool_),
                            np.ascontiguousarray(opening_ends, dtype=float).reshape(m, 2),
                            np.ascontiguousarray(np.broadcast_to(np.asarray(scale, dtype=float), (m,))),
                            src, connected)


@njit(exact=True)
def _pressure_factor(ev, nv, loaded, ends, scale, source, connected):
    """Eq. (15) at each vertex (the largest opening of the loaded facets there over
    delta_bar' delta~, clipped to [0, 1]; unloaded facets 0), then, if ``connected``, at most
    the bottleneck of the widest path from a source (:func:`_connected`)."""
    m = ev.shape[0]
    vmax = np.full(nv, -np.inf)
    for i in range(m):
        if loaded[i]:
            for k in range(2):
                vmax[ev[i, k]] = max(vmax[ev[i, k]], ends[i, k])
    fp = np.zeros((m, 2))
    for i in range(m):
        if loaded[i]:
            for k in range(2):
                fp[i, k] = min(max(vmax[ev[i, k]] / scale[i], 0.0), 1.0)
    if connected:
        best = _connected(ev, nv, loaded, fp, source)
        for i in range(m):
            for k in range(2):
                fp[i, k] = min(fp[i, k], best[i, k])
    return fp


def connected_factor(edges_vertices, loaded, fp_ends, source):
    """(m, 2): at each end of a loaded facet, the bottleneck of the widest path from a source.

    The loaded facets are the edges of a graph on the crack vertices; a facet's width is the
    smaller of its two end factors ``fp_ends`` (source facets: 1).  A vertex's value is the
    largest, over the paths from a source facet's vertex to it, of the narrowest width on the
    path: Dijkstra's search with max-min in place of the sum (compiled, :func:`_widest_paths`).
    Unloaded facets: 0."""
    ev, nv = vertex_index(edges_vertices)
    return _connected(ev, nv, np.asarray(loaded, dtype=np.bool_),
                      np.ascontiguousarray(fp_ends, dtype=float).reshape(-1, 2), np.asarray(source, dtype=np.bool_))


@njit(exact=True)
def _connected(ev, nv, loaded, fp_ends, source):
    """:func:`connected_factor` on compact vertex numbers ``ev`` (:func:`vertex_index`)."""
    m = ev.shape[0]
    n = 0
    for i in range(m):
        n += loaded[i]
    a = np.empty(n, np.int64)
    b = np.empty(n, np.int64)
    w = np.empty(n)
    mark = np.zeros(nv, np.bool_)
    j = 0
    for i in range(m):
        if loaded[i]:
            a[j], b[j] = ev[i, 0], ev[i, 1]
            w[j] = 1.0 if source[i] else min(fp_ends[i, 0], fp_ends[i, 1])
            if source[i]:
                mark[a[j]] = mark[b[j]] = True
            j += 1
    best = _widest_paths(nv, a, b, w, np.flatnonzero(mark).astype(np.int64))
    out = np.zeros((m, 2))
    for i in range(m):
        if loaded[i]:
            out[i, 0], out[i, 1] = best[ev[i, 0]], best[ev[i, 1]]
    return out


@njit
def _widest_paths(n, a, b, w, src_v):
    """Bottleneck of the widest path from any of ``src_v`` (value 1) to each of ``n`` vertices
    over the undirected edges (a, b) of width w; 0 where not connected."""
    best = np.zeros(n)
    if src_v.size == 0:
        return best
    deg = np.zeros(n + 1, np.int64)
    for k in range(a.size):
        deg[a[k] + 1] += 1
        deg[b[k] + 1] += 1
    ptr = np.cumsum(deg)
    fill = ptr[:-1].copy()
    nbr = np.empty(2 * a.size, np.int64)
    wid = np.empty(2 * a.size)
    for k in range(a.size):
        nbr[fill[a[k]]], wid[fill[a[k]]] = b[k], w[k]
        fill[a[k]] += 1
        nbr[fill[b[k]]], wid[fill[b[k]]] = a[k], w[k]
        fill[b[k]] += 1
    heap = [(-1.0, src_v[0])]
    for s in src_v:
        best[s] = 1.0
        heapq.heappush(heap, (-1.0, s))
    while len(heap) > 0:
        nb, u = heapq.heappop(heap)
        if -nb < best[u]:
            continue
        for k in range(ptr[u], ptr[u + 1]):
            c = min(best[u], wid[k])
            v = nbr[k]
            if c > best[v]:
                best[v] = c
                heapq.heappush(heap, (-c, v))
    return best


def fill_order(edges_vertices, lengths, loaded, source, index=None):
    """(order, near) of :func:`fluid_fill`: the loaded facets that are not sources and are
    connected to one, in the order of their distance along the loaded network (the mean of the
    ends' Dijkstra distances; ties by index), and per facet (m,) the end nearer the sources
    (0: va, 1: vb).  They change only when the loaded set does.  ``index``: as
    :func:`end_distances`."""
    dv = end_distances(edges_vertices, lengths, loaded, source, index)
    dist = dv.mean(axis=1)
    idx = np.flatnonzero(np.asarray(loaded, dtype=bool) & ~np.asarray(source, dtype=bool) & np.isfinite(dist))
    order = idx[np.argsort(dist[idx], kind="stable")]
    return order, (dv[:, 1] < dv[:, 0]).astype(np.int64)


def fluid_fill(edges_vertices, lengths, loaded, source, capacity, volume, order=None):
    """(wet fraction per facet (m,), near end per facet (m,), 0: va, 1: vb) of a fluid volume
    ``volume`` [m² per m of thickness] that fills the ``loaded`` facets from the ``source``
    facets outward, in :func:`fill_order` (or the given ``(order, near)``), each up to its
    ``capacity`` [m²].  The facet at the front is wet over the fraction its share of the volume
    fills, from its end nearer the sources; facets beyond it and unloaded ones are dry (0).
    The sources (the perforations, open to the wellbore) are always wet: ``volume`` is the
    fluid beyond them."""
    order, near = order if order is not None else fill_order(edges_vertices, lengths, loaded, source)
    wet = np.empty(edges_vertices.shape[0])
    _fill(np.asarray(order, dtype=np.int64), np.ascontiguousarray(capacity, dtype=float),
          np.asarray(loaded, dtype=np.bool_), np.asarray(source, dtype=np.bool_), float(volume), wet)
    return wet, near


@njit(exact=True)
def _clip01(x):
    """x clipped to [0, 1], as ``np.clip(x, 0.0, 1.0)``."""
    x = x if x > 0.0 else 0.0
    return x if x < 1.0 else 1.0


@njit(exact=True)
def _fill(order, cap, loaded, source, volume, wet):
    """:func:`fluid_fill`'s wet fractions into ``wet`` (m,): the loaded sources wet, the facets of
    ``order`` each over the fraction of its capacity the volume left by those before it fills,
    the rest dry.  The running sum is numpy's ``cumsum(cap) - cap``, in the same order."""
    for i in range(wet.size):
        wet[i] = 1.0 if loaded[i] and source[i] else 0.0
    acc = 0.0
    for k in range(order.size):
        c = cap[order[k]]
        acc += c
        wet[order[k]] = _clip01((volume - (acc - c)) / (c if c > 1e-300 else 1e-300))


def wet_points(wet, near, s_q):
    """(m, nq) wet fraction at each Gauss point (abscissae ``s_q`` in [0, 1] from va): a facet
    wet over the fraction ``wet`` from its ``near`` end, each point's share (1/nq) filled in
    turn, so that the points' mean is the facet's fraction (:func:`_wet_point`)."""
    wet, near = np.ascontiguousarray(wet, dtype=float), np.ascontiguousarray(near, dtype=np.int64)
    out = np.empty((wet.size, len(s_q)))
    _wet_points(wet, near, _point_rank(s_q), out)
    return out


@njit(exact=True)
def _wet_points(wet, near, rank, out):
    for f in range(out.shape[0]):
        for q in range(out.shape[1]):
            out[f, q] = _wet_point(wet[f], near[f], rank[q], out.shape[1])


def _point_rank(s_q):
    """Each Gauss point's place from va (0 the nearest)."""
    return np.argsort(np.argsort(s_q)).astype(np.int64)


@njit(exact=True)
def _wet_point(wet, near, rank, nq):
    """The wet fraction of the Gauss point in place ``rank`` from va of a facet wet over the
    fraction ``wet`` from its ``near`` end (0: va, 1: vb)."""
    return _clip01(wet * nq - (rank if near == 0 else nq - 1 - rank))


@njit(exact=True)
def _row_sum(a, b, i):
    """sum_j a[i, j] b[i, j] in numpy's order for a contiguous row (its pairwise sum: one running
    sum from 0 below 8 terms, else eight running sums over blocks of 8, then the rest; numpy
    splits rows above 128 terms, which a facet's Gauss points never reach), so that the compiled
    update has the bits of ``(a * b).sum(axis=1)``."""
    n = a.shape[1]
    if n < 8:
        res = 0.0
        for j in range(n):
            res += a[i, j] * b[i, j]
        return res
    r0, r1, r2, r3 = a[i, 0] * b[i, 0], a[i, 1] * b[i, 1], a[i, 2] * b[i, 2], a[i, 3] * b[i, 3]
    r4, r5, r6, r7 = a[i, 4] * b[i, 4], a[i, 5] * b[i, 5], a[i, 6] * b[i, 6], a[i, 7] * b[i, 7]
    j = 8
    while j < n - n % 8:
        r0 += a[i, j] * b[i, j]
        r1 += a[i, j + 1] * b[i, j + 1]
        r2 += a[i, j + 2] * b[i, j + 2]
        r3 += a[i, j + 3] * b[i, j + 3]
        r4 += a[i, j + 4] * b[i, j + 4]
        r5 += a[i, j + 5] * b[i, j + 5]
        r6 += a[i, j + 6] * b[i, j + 6]
        r7 += a[i, j + 7] * b[i, j + 7]
        j += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while j < n:
        res += a[i, j] * b[i, j]
        j += 1
    return res


@njit(exact=True)
def _send_rows(D, opening, weights, ones, source, threshold, floor, out):
    """This rank's rows of the network's state, (nf, 3) or with the capacity (nf, 4): whether
    the facet is in the network (its mean damage at least ``threshold``, or a source), its
    opening at both ends (the first and last Gauss points), and the fluid it holds: its mean
    aperture times its length, at least ``floor`` (delta_bar' delta~ times the length)."""
    nf, nq = D.shape
    for f in range(nf):
        out[f, 0] = 1.0 if _row_sum(D, ones, f) / nq >= threshold or source[f] else 0.0
        out[f, 1], out[f, 2] = opening[f, 0], opening[f, nq - 1]
        if out.shape[1] > 3:
            c = _row_sum(opening, weights, f)
            out[f, 3] = c if c >= floor[f] else floor[f]


@njit(exact=True)
def _point_loads(fp_ends, regularized, rise, s_q, source, loaded, volume, wet, near, rank, fp_q, wet_q, fp_wet, S0,
                 cS):
    """The load at each Gauss point of this rank's facets: the pressure factor f_p interpolated
    from the facet's ends (``rise`` = 1 - s_q), 1 on sources, 0 on unloaded facets (all 1 on
    loaded ones if not ``regularized``); with a fluid ``volume``, the wet fraction
    (:func:`_wet_point`) and f_p times it; the separation law (S0, cS) of eq. (16)
    (:func:`hydrofrac.riemann.hydraulic_law_pt`)."""
    nf, nq = fp_q.shape
    for f in range(nf):
        for q in range(nq):
            v = 1.0
            if regularized and not source[f]:
                v = fp_ends[f, 0] * rise[q] + fp_ends[f, 1] * s_q[q]
            if not loaded[f]:
                v = 0.0
            fp_q[f, q] = v
            on = 1.0 if loaded[f] else 0.0
            if volume:
                w = _wet_point(wet[f], near[f], rank[q], nq)
                wet_q[f, q] = w
                fp_wet[f, q] = v * w
                on = on * w
            S0[f, q, 0], cS[f, q] = rm.hydraulic_law_pt(on, v)
            S0[f, q, 1] = 0.0


@dataclass(frozen=True)
class HydraulicParams:
    """Hydraulic loading of a crack network.

    pressure : p_h(t) [Pa], a piecewise-linear table
    sources : facet tags of the hydraulic sources (perforations)
    delta_bar : regularisation delta_bar' in (0, 1] of the pressure factor (eq. 15)
    regularized : False = f_p = 1 on a loaded component the instant it is connected
    threshold : mean damage at which a facet joins the network
    connected : True = a facet end's factor is at most the narrowest opening on the widest path
        from a source to it (the load reaches only what open cracks connect to the wellbore;
        docs/model.md, "The pressure factor through connected apertures"); False = eq. (15) at
        each vertex alone
    volume : V(t) [m² per m of thickness], the fluid in the network, a piecewise-linear table
        (pumped in, or flowing back out): it fills the loaded network from the sources and
        the load ends at its front (:func:`fluid_fill`); None = unlimited (the paper)
    """

    pressure: PiecewiseLinear
    sources: Sequence[int]
    delta_bar: float = 0.1
    regularized: bool = True
    threshold: float = 0.99
    connected: bool = True
    volume: PiecewiseLinear | None = None

    def __post_init__(self):
        if not isinstance(self.pressure, PiecewiseLinear):
            raise ValueError("pressure must be a PiecewiseLinear table of (time, pressure)")
        if not 0 < self.delta_bar <= 1:
            raise ValueError(f"delta_bar (pressure-factor regularisation delta_bar') must be in (0, 1]; "
                             f"got {self.delta_bar}")
        if not 0 < self.threshold <= 1:
            raise ValueError(f"threshold (damage at which a facet joins the network) must be in (0, 1]; "
                             f"got {self.threshold}")
        if self.volume is not None and not (isinstance(self.volume, PiecewiseLinear)
                                            and min(self.volume.values) >= 0):
            raise ValueError("volume (the fluid in the network) must be a PiecewiseLinear table of (time [s], "
                             f"volume [m^2 per m]) with no negative volume; got {self.volume!r}")
        if len(self.sources) == 0:
            raise ValueError("sources: give at least one facet tag of a perforation")
        object.__setattr__(self, "sources", tuple(int(s) for s in self.sources))


class Hydraulics:
    """The hydraulic load on the cracks of an :class:`~hydrofrac.interface.Interface`:
    network, loaded facets, pressure factor and the separation law of eq. (16)
    (:meth:`separation_traction`).  A :class:`~hydrofrac.problem.Problem` makes that law the
    interface's and calls :meth:`update` after every step."""

    def __init__(self, iface, params: HydraulicParams):
        self.iface = iface
        self.params = params
        comm = iface.solver.comm
        compat.require_tags(comm, iface.crack_tag, params.sources, "hydraulic source", "the crack tags",
                            "give the facet tag of a perforation")
        mesh = iface.solver.mesh
        tdim = mesh.topology.dim
        f_off, f_arr = compat.connectivity(mesh, tdim - 1, 0)
        local_v = np.stack([f_arr[f_off[iface.facets]], f_arr[f_off[iface.facets] + 1]], axis=1) \
            if iface.facets.size else np.zeros((0, 2), dtype=np.int32)
        self.vertices = compat.vertex_global_indices(mesh, local_v)  # (nf, 2) global ids
        # which facet end is va (the first Gauss point side)
        self.source = np.isin(iface.crack_tag, params.sources)
        s, _ = np.polynomial.legendre.leggauss(iface.nq)
        self.s_q = 0.5 * (s + 1)  # Gauss abscissae in [0, 1] from va to vb
        self.scale = params.delta_bar * iface.delta_scale
        self.comm = comm
        self.fp_q = np.zeros((iface.facets.size, iface.nq))
        self.loaded = np.zeros(iface.facets.size, dtype=bool)
        self.network = np.zeros(iface.facets.size, dtype=bool)
        self.wet_q = np.ones((iface.facets.size, iface.nq))  # fluid behind the front (volume given)
        self._components = None  # (network, sources, loaded) of the last update, all ranks
        self._fill = None  # (loaded, fill_order) of the last update, all ranks
        # the network's fixed data, gathered once per mesh (crack facets are a small part of
        # it): vertex ids, sources, delta_bar' delta~, lengths, and its vertex numbering
        parts = comm.allgather((self.vertices, self.source, self.scale, iface.length))
        self._V = np.concatenate([p[0] for p in parts]).reshape(-1, 2)
        self._Src = np.concatenate([p[1] for p in parts]).astype(bool)
        self._Sc = np.concatenate([p[2] for p in parts]).astype(float)
        self._L = np.concatenate([p[3] for p in parts]).astype(float)
        self._index = vertex_index(self._V)
        # the per-step passes' fixed inputs (:meth:`update`)
        nf = iface.facets.size
        self._ones = np.ones((nf, iface.nq))  # (the damage's row sums: D * 1 is D)
        self._floor = np.ascontiguousarray(np.broadcast_to(self.scale * iface.length, (nf,)), dtype=float)
        self._rise = 1 - self.s_q  # the weight of a facet's end va at each Gauss point
        self._rank = _point_rank(self.s_q)
        self._factor_sources = (self._Src if params.connected else np.zeros(self._Src.size, dtype=bool))
        self._no_ends, self._no_wet, self._no_near = np.zeros((nf, 2)), np.zeros(nf), np.zeros(nf, dtype=np.int64)
        counts = np.array([p[0].shape[0] for p in parts])
        offset = int(counts[: comm.rank].sum())
        self._mine = slice(offset, offset + iface.facets.size)
        self._counts = counts
        self.update()

    def _gather_state(self, send):
        """(active, opening ends, capacity or None) of every rank's facets, in rank order: one
        ``Allgatherv`` of this rank's (facets, 3 or 4) rows (:func:`_send_rows`)."""
        k = send.shape[1]
        recv = np.empty((int(self._counts.sum()), k))
        sizes = self._counts * k
        self.comm.Allgatherv(send, [recv, sizes, np.r_[0, np.cumsum(sizes)[:-1]], MPI.DOUBLE])
        cap = np.ascontiguousarray(recv[:, 3]) if k == 4 else None
        return recv[:, 0] > 0.5, np.ascontiguousarray(recv[:, 1:3]), cap

    # ----------------------------------------------------------------- per step
    def update(self):
        """Recompute the network, loaded facets and f_p from the current state (collective).
        Three compiled passes around the gather and the network's components: this rank's rows
        (:func:`_send_rows`), the pressure factor at the vertices (:func:`_pressure_factor`)
        and the fluid's front (:func:`_fill`), and the load at the Gauss points
        (:func:`_point_loads`)."""
        iface, params = self.iface, self.params
        volume = params.volume
        send = np.empty((iface.facets.size, 3 if volume is None else 4))
        # a facet holds the fluid of its mean aperture, at least δ̄'δ̃ (where it is fully loaded)
        _send_rows(iface.state[0], iface.state[1], iface.weights, self._ones, self.source,
                   float(params.threshold), self._floor, send)
        # gather the whole network's state (the fixed part was gathered with the mesh)
        A, E, Cap = self._gather_state(send)
        V, Src, mine = self._V, self._Src, self._mine
        # the components change only when a facet joins or leaves the network: reuse them
        # otherwise (the gathered arrays are the same on every rank, and so is the choice)
        cached = self._components
        if cached is not None and np.array_equal(cached[0], A):
            loaded = cached[2]
        else:
            loaded = loaded_facets(V, A, Src, self._index)
            self._components = (A, Src, loaded)
        self.network = A[mine]
        self.loaded = loaded[mine]
        fp_ends = (_pressure_factor(*self._index, loaded, E, self._Sc, self._factor_sources, params.connected)[mine]
                   if params.regularized else self._no_ends)
        wet, near = self._no_wet, self._no_near
        if volume is not None:
            # the fill order changes only with the loaded set (the same on every rank)
            if self._fill is None or not np.array_equal(self._fill[0], loaded):
                self._fill = (loaded, fill_order(V, self._L, loaded, Src, self._index))
            order, near = self._fill[1]
            wet = np.empty(A.size)
            _fill(order, Cap, loaded, Src, float(volume(iface.solver.t)), wet)
            wet, near = wet[mine], near[mine]
        shape = (iface.facets.size, iface.nq)
        fp_q, wet_q, fp_wet, S0, cS = np.empty(shape), np.empty(shape), np.empty(shape), np.empty(shape + (2,)), \
            np.empty(shape)
        _point_loads(fp_ends, params.regularized, self._rise, self.s_q, self.source, self.loaded, volume is not None,
                     wet, near, self._rank, fp_q, wet_q, fp_wet, S0, cS)
        if volume is not None:
            self.wet_q = wet_q
        # the fraction of p_h a point carries: f_p behind the fluid's front
        self.fp_q = fp_q if volume is None else fp_wet
        # the separation law per Gauss point until the next update (eq. 16)
        self._S0_unit, self._cS = S0, cS

    def separation_traction(self, t):
        """Eq. (16) on loaded facets, S = 0 elsewhere, as the affine law of the interface
        kernel: S^1 = -f_p p_h - (1 - f_p) <-s_B^1> = p_h S0 + cS <-s_B^1>, S^2 = 0."""
        return self._S0_unit, self._cS, self.params.pressure(t)

    # ----------------------------------------------------------------- output
    def fields(self):
        out = {"f_p": self.fp_q, "loaded": np.repeat(self.loaded[:, None], self.iface.nq, axis=1).astype(float),
               "network": np.repeat(self.network[:, None], self.iface.nq, axis=1).astype(float)}
        if self.params.volume is not None:
            out["wet"] = self.wet_q * out["loaded"]
        return out

    def facet_fp(self):
        """Each crack facet's mean pressure factor f_p over its Gauss points (nf,): the row sums
        over n_q, as ``fp_q.mean(axis=1)`` computes them, without its overhead (monitors ask
        every step)."""
        return self.fp_q.sum(axis=1) / self.iface.nq

    def fluid(self):
        """(volume of the loaded network's apertures ∫ max(δ, 0) ds [m²], wet length [m],
        fluid volume V(t) [m², inf without a volume]) (global)."""
        w, loaded = self.iface.weights, self.loaded[:, None]
        loc = np.array([(np.maximum(self.iface.state[1], 0.0) * w * loaded).sum(), (self.wet_q * w * loaded).sum()])
        self.comm.Allreduce(MPI.IN_PLACE, loc, op=MPI.SUM)  # (a buffer: no pickling)
        vol, wet = loc
        v = self.params.volume
        return float(vol), float(wet), (float(v(self.iface.solver.t)) if v is not None else float("inf"))

    def loaded_length(self):
        """Length of the loaded network weighted by f_p, and total network length [m] (global)."""
        w = self.iface.weights
        both = np.array([(self.fp_q * w).sum(), (self.network[:, None] * w).sum()])
        self.comm.Allreduce(MPI.IN_PLACE, both, op=MPI.SUM)  # (one reduction, a buffer)
        return float(both[0]), float(both[1])


def end_distances(edges_vertices, lengths, active, source, index=None):
    """(m, 2): each facet end's distance along the network (through ``active`` facets) from the
    nearest vertex of an active source facet; inf where not connected.  ``index``:
    :func:`vertex_index` of ``edges_vertices``, if known (the same graph, numbered once)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra
    ev, n = vertex_index(edges_vertices) if index is None else index
    active, source = np.asarray(active, dtype=bool), np.asarray(source, dtype=bool)
    e = ev[active]
    w = np.asarray(lengths, dtype=float)[active]
    G = coo_matrix((np.r_[w, w], (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()
    src = np.unique(ev[active & source].reshape(-1))
    if src.size == 0:
        return np.full(ev.shape, np.inf)
    d = dijkstra(G, indices=src, min_only=True)
    return d[ev]


def network_distance(edges_vertices, lengths, active, source):
    """Distance along the network (through active facets) from the nearest source facet,
    per facet (mean of its two end vertices; inf if not connected)."""
    return end_distances(edges_vertices, lengths, active, source).mean(axis=1)
