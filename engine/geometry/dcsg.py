"""Directed cyclic scene graphs (DCSG) for context-free L-systems (thesis 4.2.2-4.4).

A context-free pL-system (engine/lsystem/grammar.py) is translated into a graph
instead of being derived to a string (Gervautz & Traxler 1996; their names in
brackets):

* a **rule node** [selection node] per distinct (module, remaining steps,
  incoming turtle width and material): its *alternatives* are the matching
  productions, chosen at ray time from the module's path hash exactly as
  `lsystem.derive` chooses them, so the graph and the derived string agree
  for every seed;
* a **transformation node** [transformation node] per child edge: the rigid
  turtle frame at which the child's expansion starts, relative to its
  parent's frame (turtle moves are rigid, so t is shared by all frames);
* parameters are folded into the nodes they select [assignment / value
  nodes]: A(1) and A(2) are different nodes, and so are the same module at
  different remaining steps, which is where recursion goes (a *reference*
  to the node one level down);
* a **terminal node** draws the one primitive of a module the turtle draws
  (``F`` a cylinder or frustum, ``@O`` a sphere), in its own frame.

Congruent subtrees (same module, steps and incoming state) are one node, so
the graph has O(steps x distinct modules) nodes however many primitives it
stands for. Each node's bounding box (in its own frame, the union over its
alternatives) comes from one memoised bottom-up pass at setup.

A ray walks the graph from the root, mapping itself into each child frame
whose box it enters and choosing alternatives by hash: the expansion is lazy
and per ray, nothing is unrolled. A hit reports the primitive's **address**
(7.4.2), the path hash of its terminal module: the same hash
`lsystem.derive` gives that module in the derived string, so addresses are
unique (up to 64-bit collisions) and equal between graph and string. The
hash of the innermost enclosing OL stub (`ol stub:` directives) comes with it.

Frames: a node's frame is the turtle's start frame (p = 0, H = +Z, L = -X,
U = -Y, engine/lsystem/turtle.py). A child starting at turtle frame E (4x4, columns
L U H p, in parent coordinates) maps to its parent by E @ M0 (M0 = the start
frame, its own inverse). A node also has an *exit*: the turtle frame and
width/material after its whole expansion, which places its right siblings.
A grammar whose alternatives for one node leave the turtle in different
exits cannot be a DCSG (a later sibling's frame would depend on the choice);
like a context-sensitive grammar it is refused with `DCSGUnsupported`, and
the caller derives the string and instances its primitives instead.
"""
import heapq
import math
from collections import namedtuple

import numpy as np
from numba import njit, prange

from ..core import features
from ..lsystem import grammar as LS
from ..lsystem import derivation
from ..core.affine import apply_transposed, cross, normal_through, unit, xform_ray
from ..core.jit import CORE, INLINE, as_float32, as_float64, as_uint64, typed
from .primitives import KIND_IDS, octa_encode, prim_hits, prim_nfaces, prim_point, prim_surface
from ..core.sampling import next_float, stream_state
from ..core.scene import SceneError
# the trace buffer's header words for the float64 section (engine/geometry/trace_layout.py)
H_F64 = 4
from ..lsystem.turtle import TurtleState, to_primitives
from .wide_bvh import ctz, descend, drop_far, pop_node, ray_slabs, slab4

# The turtle's start frame: columns L = -X, U = -Y, H = +Z.
M0 = np.diag([-1.0, -1.0, 1.0, 1.0])
# Exits of alternatives must agree to this (relative to the node's extent).
EXIT_TOLERANCE = 1e-9
# Edges whose subtree has at most this many primitive paths get exact boxes; the
# whole pass evaluates at most EXACT_ROWS support directions (engine setup time).
EXACT_PATHS = 1 << 16
EXACT_ROWS = 1 << 23
# The expansion cache (thesis 4.4): subtrees of at most CACHE_PATHS primitives
# are kept expanded, each a 4-wide BVH over its primitives, within CACHE_MB.
CACHE_PATHS = 1 << 14
# Terminal kind of an organ (`~(name)` with a mesh, scene.LSystem.organs): its row's
# params[0] is the organ's index; never an analytic primitive kind.
ORGAN = 63
CACHE_MB = 64.0
# bytes one cached primitive costs: its item (inverse, row, chain) and BVH share
CACHE_ITEM_BYTES = 12 * 8 + 3 * 4 + 4 * 4 + 48
_CORNERS = np.array([[x, y, z, 1.0] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])


class DCSGUnsupported(SceneError):
    """The grammar cannot be a DCSG (context, or choice-dependent exits); derive it instead."""


class _Node:
    __slots__ = ("key", "alts", "prim", "exit", "state", "lo", "hi", "n_prims", "depth", "stub",
                 "paths", "edge_boxes", "fixed")

    def __init__(self, key):
        self.key = key
        self.alts = []          # [(cumulative probability, [(child node, 4x4 child->parent, j)])]
        self.prim = None        # (kind id, params (4,), 3x4 prim->node, material) for terminals
        self.stub = False


DCSGArrays = namedtuple("DCSGArrays", [
    "node_lo", "node_hi",            # float64[N, 3]: box in the node's frame
    "node_alt0", "node_nalt",        # int64[N]: its alternatives
    "node_prim",                     # int64[N]: primitive row of a terminal, -1 otherwise
    "node_stub",                     # int64[N]: 1 if the node is an OL stub
    "alt_cum",                       # float64[A]: running normalised probability
    "alt_child0", "alt_nchild",      # int64[A]
    "child_node", "child_j",         # int64[C]: child node, index in the successor (hash)
    "child_inv",                     # float64[C, 3, 4]: parent frame -> child frame (-> the
                                     # primitive's frame where the child is a terminal)
    "child_rot",                     # float64[C, 3, 3]: child -> parent rotation (normals)
    "child_box",                     # float64[C, 6]: the child's subtree box in the parent frame
    "prim_kind", "prim_params",      # int64[P], float64[P, 4]
    "prim_inv",                      # float64[P, 3, 4]: node frame -> primitive
    "prim_material",                 # int64[P]
    "root", "root_hash", "stack_size", "depth",
    # the expansion cache: per node its cache entry (-1: none); per entry its root
    # record; the 4-wide records (engine/geometry/bvh.py pack_bvh, int32 words, global ids);
    # items (terminal row, chain start and length, node frame -> primitive); the
    # chains of child indices
    "node_cache", "cache_root", "cache_records",
    "item_prim", "item_chain0", "item_nchain", "item_inv", "chain_j",
    "item_stub",                     # int64[I]: chain steps to the innermost stub, -1: none
])
_CACHE_FIELDS = ("node_cache", "cache_root", "cache_records", "item_prim", "item_chain0",
                 "item_nchain", "item_inv", "chain_j", "item_stub")


OrganTable = namedtuple("OrganTable", "index names tri cdf area box material")


def _organ_table(organs):
    """The organs' meshes for the kernels: each normalised into the box [-1, 1]^3 (so
    a terminal's box is its transform's, as for the analytic primitives; the box
    frame `box` (4x4) goes into the terminal's transform), as triangles (T, 9) with
    their cumulative area (for area samples), local area and material. `organs`:
    name -> object with vertices (V, 3), triangles (T, 3), material (scene index),
    already validated (engine/geometry/assembly.py)."""
    names = list(organs)
    tri, cdf, area, box, mat = [], [], [], [], []
    for name in names:
        m = organs[name]
        v = np.asarray(m.vertices, np.float64).reshape(-1, 3)
        t = np.asarray(m.triangles, np.int64).reshape(-1, 3)
        lo, hi = v.min(axis=0), v.max(axis=0)
        c, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        # a flat leaf has no thickness: a thin box keeps the frame invertible
        half = np.maximum(half, max(1e-3 * half.max(), 1e-9))
        b = np.eye(4)
        b[:3, :3] = np.diag(half)
        b[:3, 3] = c
        q = ((v - c) / half)[t]                                   # (T, 3, 3)
        a = 0.5 * np.linalg.norm(np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]), axis=1)
        tri.append(q.reshape(-1, 9))
        cdf.append(np.cumsum(a) / a.sum())
        area.append(float(a.sum()))
        box.append(b)
        mat.append(int(m.material))
    return OrganTable({n: i for i, n in enumerate(names)}, names, tri, cdf, area, box, mat)


class DCSG:
    """The graph of one context-free grammar at a derivation length (see the module docstring)."""

    def __init__(self, grammar, steps=None, angle=None, width=None, cache_mb=CACHE_MB, organs=None):
        if not grammar.is_context_free:
            raise DCSGUnsupported(f"{grammar.source_name}: a context-sensitive grammar cannot be a "
                                  "cyclic scene graph (its context crosses branches); it is derived "
                                  "to a string and its primitives instanced instead")
        self.grammar = grammar
        self.steps = grammar.derivation_length if steps is None else int(steps)
        if self.steps is None:
            self.steps = derivation.check_termination(grammar)
            if self.steps is None:
                raise DCSGUnsupported(f"{grammar.source_name}: give a derivation length")
        self.angle = grammar.angle if angle is None else float(angle)
        self.width = grammar.width if width is None else float(width)
        self._stubs = {s.symbol: s.levels for s in grammar.ol_stubs}
        self.organs = _organ_table(organs or {})
        self.nodes = []
        self._memo = {}
        # the axiom is the successor of a virtual root of hash splitmix64(seed), so
        # axiom module i gets lsystem.root_hash(seed, i) as in derive()
        self.root = self._rule(None, self.steps + 1, (self.width, None, 0), [list(grammar.axiom)])
        self.root_hash = LS.splitmix64(grammar.seed & LS.MASK)
        self._tighten_boxes()
        self.cache_bytes = int(max(float(cache_mb), 0.0) * 2 ** 20)

    # ------------------------------------------------------------ building

    def _node(self, module, steps, state):
        """The node of `module` with `steps` rewrites left, entered with turtle
        (width, previous drawn width, material) = state."""
        alts = self.grammar.alternatives(module) if steps > 0 else []
        if not alts:
            steps = 0                    # unchanged from here on: one node for all levels
        key = (module, steps, state)
        n = self._memo.get(key)
        if n is not None:
            return n
        if not alts:
            n = self._terminal(key, module, state)
        else:
            succ = [prod.apply(module) for prod, _ in alts]
            n = self._rule(module, steps, state, succ, [p for _, p in alts])
        self._memo[key] = n
        return n

    def _turtle(self, state):
        ts = TurtleState(self.angle, self.width)
        ts.width, ts.drawn, ts.material = state
        return ts

    def _terminal(self, key, module, state):
        n = self._new(key)
        ts = self._turtle(state).apply(module)
        geom = ts.geometry()
        prims = to_primitives(geom)
        placed = [o for o in geom.organs if o.name in self.organs.index]
        if placed:           # an organ with a mesh: its normalised box frame in the turtle's
            k = self.organs.index[placed[0].name]
            xf = (np.asarray(placed[0].matrix, np.float64) @ self.organs.box[k])[:3]
            n.prim = (ORGAN, np.array([k, 0.0, 0.0, 0.0]), xf, -1 - k)
            w = _CORNERS @ xf.T
            n.lo, n.hi = w.min(axis=0), w.max(axis=0)
            n.n_prims = 1
        elif prims:
            p = prims[0]
            xf = np.asarray(p.transform, np.float64)[:3]
            params = np.zeros(4)
            params[:len(p.params)] = p.params
            n.prim = (KIND_IDS[p.kind], params, xf, int(p.material))
            w = _CORNERS @ xf.T
            n.lo, n.hi = w.min(axis=0), w.max(axis=0)
            n.n_prims = 1
        n.exit, n.state = ts.matrix(), (ts.width, ts.drawn, ts.material)
        return n

    def _new(self, key):
        n = _Node(key)
        n.lo, n.hi = np.full(3, np.inf), np.full(3, -np.inf)
        n.n_prims = 0
        n.depth = 0
        self.nodes.append(n)
        return n

    def _rule(self, module, steps, state, successors, probs=(1.0,)):
        key = (module, steps, state)
        n = self._new(key)
        levels = self._stubs.get(module.symbol, ()) if module is not None else ()
        # a stub at every level, or at the listed derivation steps (level = steps done)
        n.stub = module is not None and module.symbol in self._stubs and (
            levels is None or (self.steps - steps) in levels)
        cum = 0.0
        exits, n_prims = [], 0
        for succ, p in zip(successors, probs):
            cum += p
            weight = p if len(probs) > 1 else 1      # deterministic counts stay exact ints
            children, ts, depth = [], self._turtle(state), 0
            for j, c in enumerate(succ):
                if c.symbol in "[]":
                    ts.apply(c)
                    continue
                child = self._node(c, steps - 1, (ts.width, ts.drawn, ts.material))
                to_parent = ts.matrix() @ M0
                if child.n_prims:
                    children.append((child, to_parent, j))
                    n_prims += weight * child.n_prims
                    w = _box_through(child.lo, child.hi, to_parent)
                    n.lo, n.hi = np.minimum(n.lo, w[0]), np.maximum(n.hi, w[1])
                    depth = max(depth, child.depth + 1)
                e = to_parent @ child.exit
                ts.l, ts.u, ts.h, ts.p = (tuple(e[:3, k]) for k in range(4))
                ts.fid = -1
                ts.width, ts.drawn, ts.material = child.state
            if ts.depth:
                raise SceneError(f"{self.grammar.source_name}: a successor of {module} leaves "
                                 f"{ts.depth} '[' open")
            n.alts.append((cum, children))
            n.depth = max(n.depth, depth)
            exits.append((ts.matrix(), (ts.width, ts.drawn, ts.material)))
        n.exit, n.state = exits[0]
        scale = 1.0 + float(np.abs(exits[0][0][:3, 3]).max())
        for e, s in exits[1:]:
            if s != n.state or np.abs(e - n.exit).max() > EXIT_TOLERANCE * scale:
                raise DCSGUnsupported(
                    f"{self.grammar.source_name}: the alternatives of {module} leave the turtle in "
                    "different places, so the frame of what follows depends on the choice; such a "
                    "grammar is derived to a string instead of a scene graph")
        n.n_prims = n_prims
        return n

    # ------------------------------------------------------------ tight boxes

    def _topological(self):
        """All nodes, parents before children (a memoised child may predate its parent)."""
        order, seen, stack = [], set(), [(n, False) for n in reversed(self.nodes)]
        while stack:
            n, done = stack.pop()
            if done:
                order.append(n)
            elif id(n) not in seen:
                seen.add(id(n))
                stack.append((n, True))
                stack.extend((c, False) for _, ch in n.alts for c, _, _ in ch)
        return order[::-1]

    def _tighten_boxes(self):
        """Each edge's box in its parent's frame, and each node's box (the union of its
        edges', over all alternatives). Carrying a child's box through the rotation
        into the parent's frame inflates it at every level (x5.6 in volume over ten
        forks of a tree), so an edge whose subtree has at most EXACT_PATHS primitive
        paths gets the exact box of its primitives' boxes instead: the subtree's
        support function along the parent's six axes, h(e) = max over children of
        e.t + h_child(R^T e). One pass, parents first, carries every such edge's
        directions down the graph at once. Larger subtrees fall back to the child's
        box through the transform (exact boxes below them keep that tight too)."""
        order = self._topological()
        for n in reversed(order):
            n.paths = 1 if n.prim is not None else sum(c.paths for _, ch in n.alts for c, _, _ in ch)
            n.edge_boxes = [np.full((len(ch), 6), np.nan) for _, ch in n.alts]
        axes = np.vstack([np.eye(3), -np.eye(3)])
        edges, pending, rows = [], {}, 0
        for n in order:
            for a, (_, ch) in enumerate(n.alts):
                for i, (c, to_parent, _) in enumerate(ch):
                    if c.paths <= EXACT_PATHS and rows + 6 * c.paths <= EXACT_ROWS:
                        pending.setdefault(id(c), []).append(
                            (axes @ to_parent[:3, :3], axes @ to_parent[:3, 3],
                             np.full(6, len(edges)), np.arange(6)))
                        edges.append((n, a, i))
                        rows += 6 * c.paths
        h = np.full((len(edges), 6), -np.inf)
        for n in order:
            batch = pending.pop(id(n), None)
            if not batch:
                continue
            D, off, tag, slot = (np.concatenate(x) for x in zip(*batch))
            if n.prim is not None:
                corners = _CORNERS @ n.prim[2].T            # the primitive's box, node frame
                np.maximum.at(h, (tag, slot), off + (D @ corners.T).max(axis=1))
                continue
            for _, ch in n.alts:
                for c, to_parent, _ in ch:
                    pending.setdefault(id(c), []).append(
                        (D @ to_parent[:3, :3], off + D @ to_parent[:3, 3], tag, slot))
        for (n, a, i), v in zip(edges, h):
            n.edge_boxes[a][i] = np.concatenate([-v[3:], v[:3]])     # lo, hi
        for n in reversed(order):                         # children first: fallbacks, unions
            if n.prim is not None:
                continue
            lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
            for (_, ch), boxes in zip(n.alts, n.edge_boxes):
                for (c, to_parent, _), b in zip(ch, boxes):
                    if np.isnan(b[0]):
                        b[:3], b[3:] = _box_through(c.lo, c.hi, to_parent)
                    lo, hi = np.minimum(lo, b[:3]), np.maximum(hi, b[3:])
            n.lo, n.hi = lo, hi

    # ------------------------------------------------------------ expansion cache

    def _expansion_cache(self, ids, node_prim):
        """The expanded subgraphs (thesis 4.4): a deterministic subtree of at most
        CACHE_PATHS primitives is kept unrolled in its root's frame, a 4-wide SAH BVH
        over its primitives, so a ray entering it walks that BVH instead of the
        graph's levels (no transforms per level, tight boxes per primitive). The graph
        is memoised, so one expansion serves every place the subtree occurs. Which
        subtrees: the topmost that qualify, most used first, within `cache_bytes`.
        The cache is filled at setup and then only read: rays in parallel threads
        share it with no locks, and the image does not depend on the order rays come
        in (the thesis's LRU evicts during the render). Its hit rate is the share of
        primitive visits that the cache serves, computed from the graph's counts."""
        from .bvh import build_bvh, pack_bvh
        order = self._topological()
        for n in reversed(order):
            n.fixed = n.prim is not None or (len(n.alts) == 1 and all(
                c.fixed for c, _, _ in n.alts[0][1]))
        uses = {id(self.root): 1.0}
        for n in order:                           # parents first: how often each node occurs
            u = uses.get(id(n), 0.0)
            prev = 0.0
            for cum, ch in n.alts:
                w = (cum - prev) if len(n.alts) > 1 else 1.0
                prev = cum
                for c, _, _ in ch:
                    uses[id(c)] = uses.get(id(c), 0.0) + u * w

        def cacheable(n):
            return n.prim is None and n.fixed and 2 <= n.paths <= CACHE_PATHS

        frontier = [self.root] if cacheable(self.root) else []
        seen = {id(self.root)}
        for n in order:
            if cacheable(n):
                continue
            for _, ch in n.alts:
                for c, _, _ in ch:
                    if cacheable(c) and id(c) not in seen:
                        seen.add(id(c))
                        frontier.append(c)
        # most served primitive visits first; a subtree that does not fit gives way to
        # its children, so a small cache still holds the lower levels
        heap = [(-uses[id(n)] * n.paths, k, n) for k, n in enumerate(frontier)]
        heapq.heapify(heap)
        tick = len(heap)
        N = len(self.nodes)
        node_cache = np.full(N, -1, np.int64)
        cache_bvh, records = [], []
        it_prim, it_c0, it_nc, it_inv, chains, it_stub = [], [], [], [], [], []
        used, served, cached, n_chain = 0, 0.0, set(), 0
        memo = {}

        def expanded(m):
            """m's primitives in m's frame: (terminal rows, 4x4 primitive -> m transforms,
            their chains of child indices, flat, with offsets, and where along its chain
            each meets its innermost OL stub (-1: none below m)), built once per
            distinct node with batched products."""
            got = memo.get(id(m))
            if got is not None:
                return got
            if m.prim is not None:
                full = np.eye(4)
                full[:3] = m.prim[2]
                got = (np.array([node_prim[ids[id(m)]]]), full[None], np.zeros(0, np.int64),
                       np.zeros(2, np.int64), np.full(1, -1, np.int64))
            else:
                parts = []
                for c, to_parent, j in m.alts[0][1]:
                    r, x, f, o, st = expanded(c)
                    # prepend j to every chain of the child; a deeper stub stays innermost
                    st = np.where(st >= 0, st + 1, 1 if c.stub else -1)
                    parts.append((r, to_parent @ x, np.insert(f, o[:-1], j), o + np.arange(o.shape[0]),
                                  st))
                rows = np.concatenate([q[0] for q in parts])
                xs = np.concatenate([q[1] for q in parts])
                flat = np.concatenate([q[2] for q in parts])
                base = np.cumsum([0] + [q[2].shape[0] for q in parts])
                offs = np.concatenate([q[3][:-1] + b for q, b in zip(parts, base)] + [[base[-1]]])
                got = (rows, xs, flat, offs.astype(np.int64), np.concatenate([q[4] for q in parts]))
            memo[id(m)] = got
            return got

        while heap:
            _, _, n = heapq.heappop(heap)
            if id(n) in cached:
                continue
            if used + n.paths * CACHE_ITEM_BYTES > self.cache_bytes:
                for c, _, _ in n.alts[0][1]:
                    if cacheable(c) and id(c) not in cached:
                        tick += 1
                        heapq.heappush(heap, (-uses[id(c)] * c.paths, tick, c))
                continue
            cached.add(id(n))
            rows, xf, cflat, coff, stub_at = expanded(n)
            corners = np.einsum("pij,kj->pki", xf[:, :3], _CORNERS)       # primitive boxes
            bvh = build_bvh(corners.min(axis=1), corners.max(axis=1))
            _pf, pi, nrec, _need = pack_bvh(bvh.node_min, bvh.node_max, bvh.node_a, bvh.node_count)
            pi = pi.reshape(nrec, 32).copy()
            r0, i0 = sum(x.shape[0] for x in records), sum(x.shape[0] for x in it_prim)
            inner, leaf = pi[:, 28:] == 0, pi[:, 28:] > 0
            pi[:, 24:28][inner] += r0                  # global record ids
            pi[:, 24:28][leaf] += i0                   # global item ids
            node_cache[ids[id(n)]] = len(cache_bvh)
            cache_bvh.append(r0)
            records.append(pi)
            order_ = bvh.items
            it_prim.append(rows[order_])
            lens = np.diff(coff)[order_]
            it_nc.append(lens)
            it_c0.append(n_chain + np.concatenate([[0], np.cumsum(lens)[:-1]]).astype(np.int64))
            chains.append(np.concatenate([cflat[coff[k]:coff[k + 1]] for k in order_])
                          if lens.sum() else np.zeros(0, np.int64))
            n_chain += int(lens.sum())
            it_inv.append(np.linalg.inv(xf[order_])[:, :3])
            it_stub.append(stub_at[order_])
            used += n.paths * CACHE_ITEM_BYTES
            served += uses[id(n)] * n.paths
        self.cache_stats = {"cache_subgraphs": len(cache_bvh), "cache_primitives": int(sum(x.shape[0] for x in it_prim)),
                            "cache_bytes": int(used), "cache_limit_bytes": self.cache_bytes,
                            # (a subtree also reached beside a cached one counts twice: capped)
                            "cache_hit_rate": round(min(served / max(self.root.n_prims, 1), 1.0), 6)}
        memo.clear()
        rec = np.concatenate(records) if records else np.zeros((0, 32), np.int32)

        def cat(xs, dt, shape=(-1,)):
            return (np.concatenate(xs) if xs else np.zeros(0)).astype(dt).reshape(shape)

        return (node_cache, np.array(cache_bvh, np.int64), rec, cat(it_prim, np.int64),
                cat(it_c0, np.int64), cat(it_nc, np.int64), cat(it_inv, np.float64, (-1, 3, 4)),
                cat(chains, np.int64), cat(it_stub, np.int64))

    # ------------------------------------------------------------ reading

    @property
    def implicit_primitives(self):
        """Primitives the graph stands for (expected value where choices are stochastic)."""
        v = self.root.n_prims
        return int(round(v)) if not self.grammar.is_stochastic else float(v)

    def stats(self):
        a = self.arrays()
        nbytes = sum(x.nbytes for x in a if isinstance(x, np.ndarray))
        cache = sum(getattr(a, k).nbytes for k in _CACHE_FIELDS)
        return {"dcsg_nodes": len(self.nodes),
                "alternatives": int(a.alt_cum.shape[0]), "edges": int(a.child_node.shape[0]),
                "terminal_primitives": int(a.prim_kind.shape[0]),
                "primitives": self.implicit_primitives, "depth": int(self.root.depth),
                "bytes": int(nbytes), "graph_bytes": int(nbytes - cache), **self.cache_stats}

    def bounds(self):
        """Object-space box of everything the graph draws (primitive extents included)."""
        return self.root.lo.copy(), self.root.hi.copy()

    def arrays(self):
        """The flat arrays the ray kernels read (built once, cached)."""
        if getattr(self, "_arrays", None) is not None:
            return self._arrays
        ids = {id(n): i for i, n in enumerate(self.nodes)}
        N = len(self.nodes)
        node_lo, node_hi = np.zeros((N, 3)), np.zeros((N, 3))
        node_alt0, node_nalt = np.zeros(N, np.int64), np.zeros(N, np.int64)
        node_prim, node_stub = np.full(N, -1, np.int64), np.zeros(N, np.int64)
        alt_cum, alt_c0, alt_nc = [], [], []
        ch_node, ch_j, ch_inv, ch_rot, ch_box = [], [], [], [], []
        p_kind, p_params, p_inv, p_mat = [], [], [], []
        widest = 1
        for i, n in enumerate(self.nodes):
            node_lo[i], node_hi[i] = n.lo, n.hi
            node_stub[i] = n.stub
            node_alt0[i], node_nalt[i] = len(alt_cum), len(n.alts)
            for (cum, children), boxes in zip(n.alts, n.edge_boxes):
                alt_cum.append(cum)
                ch_box.extend(boxes)
                alt_c0.append(len(ch_node))
                alt_nc.append(len(children))
                widest = max(widest, len(children))
                for c, to_parent, j in children:
                    ch_node.append(ids[id(c)])
                    ch_j.append(j)
                    inv = np.linalg.inv(to_parent)
                    if c.prim is not None:       # a terminal's edge goes straight to its primitive
                        full = np.eye(4)
                        full[:3] = c.prim[2]
                        inv = np.linalg.inv(full) @ inv
                    ch_inv.append(inv[:3])
                    ch_rot.append(to_parent[:3, :3])
            if n.prim is not None:
                kind, params, xf, mat = n.prim
                node_prim[i] = len(p_kind)
                p_kind.append(kind)
                p_params.append(params)
                full = np.eye(4)
                full[:3] = xf
                p_inv.append(np.linalg.inv(full)[:3])
                p_mat.append(mat)
        self._arrays = DCSGArrays(
            node_lo, node_hi, node_alt0, node_nalt, node_prim, node_stub,
            np.array(alt_cum, np.float64), np.array(alt_c0, np.int64), np.array(alt_nc, np.int64),
            np.array(ch_node, np.int64), np.array(ch_j, np.int64),
            np.array(ch_inv, np.float64).reshape(-1, 3, 4), np.array(ch_rot, np.float64).reshape(-1, 3, 3),
            np.array(ch_box, np.float64).reshape(-1, 6),
            np.array(p_kind, np.int64), np.array(p_params, np.float64).reshape(-1, 4),
            np.array(p_inv, np.float64).reshape(-1, 3, 4), np.array(p_mat, np.int64),
            ids[id(self.root)], np.uint64(self.root_hash),
            # DFS pops one entry and pushes its children: along the deepest path each
            # interior level leaves (widest - 1) siblings, the last one `widest`
            1 + (widest - 1) * self.root.depth + 1, int(self.root.depth),
            *self._expansion_cache(ids, node_prim))
        return self._arrays

    def flatten(self, limit=2_000_000):
        """The instantiation the graph stands for, in string order (for tests, and for
        grammars small enough to unroll): `Flattened` arrays with each primitive's
        object-space transform, address and enclosing stub's address (0: none)."""
        out = []

        def walk(n, m, h, stub):
            if n.stub:
                stub = h
            if n.prim is not None:
                if len(out) >= limit:
                    raise SceneError(f"{self.grammar.source_name}: more than {limit:,} primitives "
                                     "to flatten")
                kind, params, xf, mat = n.prim
                full = np.eye(4)
                full[:3] = xf
                out.append((kind, params, (m @ full)[:3], mat, h, stub))
                return
            for c, to_parent, j in _children(n, h):
                walk(c, m @ to_parent, LS.child_hash(h, j), stub)

        walk(self.root, np.eye(4), self.root_hash, 0)
        cols = list(zip(*out)) if out else [()] * 6
        return Flattened(np.array(cols[0], np.int64), np.array(cols[1], np.float64).reshape(-1, 4),
                         np.array(cols[2], np.float64).reshape(-1, 3, 4), np.array(cols[3], np.int64),
                         np.array(cols[4], np.uint64), np.array(cols[5], np.uint64))


Flattened = namedtuple("Flattened", "kind params transform material address stub")


def _children(n, h):
    """The children of node n under the alternative its hash h chooses (as the kernels do)."""
    if not n.alts:
        return ()
    k = 0
    if len(n.alts) > 1:
        u = LS.draw(h)
        while k < len(n.alts) - 1 and not n.alts[k][0] > u:
            k += 1
    return n.alts[k][1]


def _box_through(lo, hi, m):
    c = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    w = c @ m[:3].T
    return w.min(axis=0), w.max(axis=0)


# ---------------------------------------------------------------- the trace blob
# All graphs of a scene in one float64 array (raw bits) inside the trace buffer
# (engine/geometry/trace_layout.py, header word H_DCSG), read through the buffer's typed
# views: an int64 header, an int32 section, a float64 section. Node, edge and
# primitive ids are global; a graph is its root node, root hash and stub table.

BLOB_HEADER = 40
(B_NGRAPH, B_VS0, B_NPRIM, B_STACK,
 B_NODE_ALT0, B_NODE_NALT, B_NODE_PRIM, B_NODE_STUB, B_ALT_C0, B_ALT_NC, B_CH_NODE, B_CH_J,
 B_PRIM_KIND, B_GRAPH_ROOT, B_GRAPH_HASH, B_GRAPH_STUB, B_STUB_ADDR,
 B_NODE_BOX, B_ALT_CUM, B_CH_INV, B_CH_ROT, B_CH_BOX, B_PRIM_PARAMS, B_PRIM_INV,
 B_NODE_CACHE, B_CACHE_ROOT, B_CACHE_REC, B_ITEM_PRIM, B_ITEM_C0, B_ITEM_NC, B_CHAIN_J,
 B_ITEM_INV, B_ORG_T0, B_ORG_NT, B_ORG_TRI, B_ORG_CDF, B_ITEM_STUB) = range(37)

# Ray scratch, in the caller's int32 stack from (even) word s0 (engine/geometry/trace_layout.py
# STACK_WORDS): per entry 7 float64 (the ray in the entry's frame, entry t), 2
# uint64 (hash, stub) and 3 int32 (node, edge it came by, depth); then the edge
# path to the current node and to the closest hit (MAX_DEPTH int32 each, for the
# hit normal), the stack of a cached subgraph's BVH (CACHE_STACK int32 nodes and
# float64 entry t's), then the result: normal, stub and address.
STACK_ENTRIES = 192
MAX_DEPTH = 192
_E_F, _E_U, _E_I = 7, 2, 3
CACHE_STACK = 64                 # a cached subgraph's BVH is at most bvh.MAX_DEPTH deep
SCRATCH_WORDS = STACK_ENTRIES * (2 * _E_F + 2 * _E_U + _E_I) + 2 * MAX_DEPTH + 3 * CACHE_STACK + 16
H_DCSG = 20       # trace header word: the blob's offset in the float64 section
NO_VSHAPE = 2 ** 31 - 1
# shape_ref of an L-system: DCSG_REF - graph (below every CSG ref, CSG_REF - root)
DCSG_REF = -(3 << 29)


StubRecord = namedtuple("StubRecord", "address node rotation parent")


def stub_records(graph, limit=1_000_000):
    """Every OL stub of the graph, sorted by address: StubRecord(address, node (index
    in graph.nodes), object rotation (3, 3) of its frame, address of the enclosing
    stub or 0). Walks only down to stubs, never to the primitives below them."""
    below = {}
    ids = {id(n): i for i, n in enumerate(graph.nodes)}

    def has_stub(n):
        v = below.get(id(n))
        if v is None:
            v = n.stub or any(has_stub(c) for _, ch in n.alts for c, _, _ in ch)
            below[id(n)] = v
        return v

    out = []

    def walk(n, h, rot, parent):
        if n.stub:
            out.append(StubRecord(h, ids[id(n)], rot, parent))
            if len(out) > limit:
                raise SceneError(f"{graph.grammar.source_name}: more than {limit:,} OL stubs; "
                                 "declare them at fewer levels")
            parent = h
        for c, to_parent, j in _children(n, h):
            if has_stub(c):
                walk(c, LS.child_hash(h, j), rot @ to_parent[:3, :3], parent)

    if has_stub(graph.root):
        walk(graph.root, graph.root_hash, np.eye(3), 0)
    out.sort(key=lambda r: r.address)
    return out


def _stub_addresses(graph):
    return np.array([r.address for r in stub_records(graph)], np.uint64)


def _u64_words(a):
    return np.ascontiguousarray(np.asarray(a, np.uint64)).view(np.int32)


def pack_blob(graphs, vs0=NO_VSHAPE, names=None):
    """The graphs' arrays as one float64 blob; their terminal primitives are the
    virtual shapes vs0, vs0 + 1, ... (graph by graph). -> (blob, prim_graph, stubs)
    where stubs[k] are graph k's StubRecords (global node ids); the kernel's stub
    index counts over all graphs' records in this order."""
    # the records first: the blob starts 64-byte aligned (geometry._build_trace,
    # dcsg_table) and so do they, as the vector loads need
    i32_keys = (B_CACHE_REC, B_NODE_ALT0, B_NODE_NALT, B_NODE_PRIM, B_NODE_STUB, B_ALT_C0, B_ALT_NC,
                B_CH_NODE, B_CH_J, B_PRIM_KIND, B_NODE_CACHE, B_CACHE_ROOT,
                B_ITEM_PRIM, B_ITEM_C0, B_ITEM_NC, B_CHAIN_J, B_ORG_T0, B_ORG_NT, B_ITEM_STUB)
    f64_keys = (B_NODE_BOX, B_ALT_CUM, B_CH_INV, B_CH_ROT, B_CH_BOX, B_PRIM_PARAMS, B_PRIM_INV,
                B_ITEM_INV, B_ORG_TRI, B_ORG_CDF)
    i32 = {k: [] for k in i32_keys}
    f64 = {k: [] for k in f64_keys}
    roots, hashes, stub_rows, stub_addr, prim_graph = [], [], [], [], []
    n0 = a0 = c0 = p0 = s0 = e0 = v0 = i0 = j0 = o0 = t0 = 0
    stack = 1
    stubs = []
    for gi, g in enumerate(graphs):
        a = g.arrays()
        if a.stack_size > STACK_ENTRIES or a.depth >= MAX_DEPTH:
            what = names[gi] if names else g.grammar.source_name
            raise SceneError(f"L-system '{what}': branching x depth needs {a.stack_size} ray-stack "
                             f"entries and {a.depth} levels (at most {STACK_ENTRIES} and "
                             f"{MAX_DEPTH - 1}); use fewer steps or split the rule")
        stack = max(stack, a.stack_size)
        i32[B_NODE_ALT0].append(a.node_alt0 + a0)
        i32[B_NODE_NALT].append(a.node_nalt)
        i32[B_NODE_PRIM].append(np.where(a.node_prim >= 0, a.node_prim + p0, -1))
        i32[B_NODE_STUB].append(a.node_stub)
        i32[B_ALT_C0].append(a.alt_child0 + c0)
        i32[B_ALT_NC].append(a.alt_nchild)
        i32[B_CH_NODE].append(a.child_node + n0)
        i32[B_CH_J].append(a.child_j)
        i32[B_PRIM_KIND].append(a.prim_kind)
        f64[B_NODE_BOX].append(np.hstack([a.node_lo, a.node_hi]))
        f64[B_ALT_CUM].append(a.alt_cum)
        f64[B_CH_INV].append(a.child_inv.reshape(-1, 12))
        f64[B_CH_ROT].append(a.child_rot.reshape(-1, 9))
        f64[B_CH_BOX].append(a.child_box.reshape(-1))
        params = a.prim_params.copy()
        params[a.prim_kind == ORGAN, 0] += o0          # global organ ids
        f64[B_PRIM_PARAMS].append(params)
        org = g.organs
        nt = np.array([x.shape[0] for x in org.tri], np.int64)
        i32[B_ORG_T0].append(t0 + np.cumsum(nt) - nt)
        i32[B_ORG_NT].append(nt)
        f64[B_ORG_TRI].append(np.concatenate(org.tri).reshape(-1) if org.tri else np.zeros(0))
        f64[B_ORG_CDF].append(np.concatenate(org.cdf) if org.cdf else np.zeros(0))
        o0 += len(org.tri)
        t0 += int(nt.sum())
        f64[B_PRIM_INV].append(a.prim_inv.reshape(-1, 12))
        i32[B_NODE_CACHE].append(np.where(a.node_cache >= 0, a.node_cache + e0, -1))
        i32[B_CACHE_ROOT].append(a.cache_root + v0)
        rec = a.cache_records.copy()
        rec[:, 24:28][rec[:, 28:] == 0] += v0
        rec[:, 24:28][rec[:, 28:] > 0] += i0
        i32[B_CACHE_REC].append(rec.reshape(-1))
        i32[B_ITEM_PRIM].append(a.item_prim + p0)
        i32[B_ITEM_C0].append(a.item_chain0 + j0)
        i32[B_ITEM_NC].append(a.item_nchain)
        i32[B_CHAIN_J].append(a.chain_j)
        i32[B_ITEM_STUB].append(a.item_stub)
        f64[B_ITEM_INV].append(a.item_inv.reshape(-1))
        e0 += a.cache_root.shape[0]
        v0 += a.cache_records.shape[0]
        i0 += a.item_prim.shape[0]
        j0 += a.chain_j.shape[0]
        roots.append(a.root + n0)
        hashes.append(a.root_hash)
        recs = stub_records(g)
        # global node ids, as the blob numbers them
        stubs.append([r._replace(node=r.node + n0) for r in recs])
        st = np.array([r.address for r in recs], np.uint64)
        stub_rows.append((s0, st.shape[0]))
        stub_addr.append(st)
        prim_graph.append(np.full(a.prim_kind.shape[0], gi, np.int64))
        n0 += a.node_lo.shape[0]
        a0 += a.alt_cum.shape[0]
        c0 += a.child_node.shape[0]
        p0 += a.prim_kind.shape[0]
        s0 += st.shape[0]
    hdr = np.zeros(BLOB_HEADER, np.int64)
    hdr[B_NGRAPH], hdr[B_VS0], hdr[B_NPRIM], hdr[B_STACK] = len(graphs), vs0, p0, stack
    parts_i32 = [(k, np.concatenate(i32[k]) if i32[k] else np.zeros(0)) for k in i32_keys]
    parts_i32 += [(B_GRAPH_ROOT, np.array(roots, np.int64)),
                  (B_GRAPH_HASH, _u64_words(hashes)),
                  (B_GRAPH_STUB, np.array(stub_rows, np.int64).reshape(-1)),
                  (B_STUB_ADDR, _u64_words(np.concatenate(stub_addr) if stub_addr else []))]
    words, n = [], 2 * BLOB_HEADER
    for key, arr in parts_i32:
        hdr[key] = n
        words.append(np.asarray(arr).astype(np.int32).reshape(-1))
        n += words[-1].size
    if n % 2:
        words.append(np.zeros(1, np.int32))
        n += 1
    floats, m = [], n // 2
    for key in f64_keys:
        arr = np.concatenate(f64[key]).reshape(-1) if f64[key] else np.zeros(0)
        hdr[key] = m
        floats.append(arr)
        m += arr.size
    assert hdr[B_CACHE_REC] % 4 == 0          # 16-byte records within a 16-byte aligned blob
    blob = np.concatenate([hdr.view(np.float64), np.concatenate(words).view(np.float64)] + floats)
    pg = np.concatenate(prim_graph) if prim_graph else np.zeros(0, np.int64)
    return blob, pg, stubs


# ---------------------------------------------------------------- ray kernels
# uint64 arithmetic with uint64 constants only: numba turns uint64 op int64 into float64.

_GOLD = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_DRAW = np.uint64(0xD1B54A32D192ED03)
_S30, _S27, _S31, _S11, _S32 = (np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11),
                               np.uint64(32))
_LO32 = np.uint64(0xFFFFFFFF)


@njit(**INLINE)
def _splitmix64(x):
    z = x + _GOLD
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@njit(**INLINE)
def _child_hash(h, j):
    return _splitmix64(h ^ (np.uint64(j + 1) * _GOLD))


@njit(**INLINE)
def _draw(h):
    return float(_splitmix64(h ^ _DRAW) >> _S11) * (2.0 ** -53)


@njit(**INLINE)
def _u64(i32, k):
    """The uint64 stored as int32 words k (low), k + 1 (high)."""
    return (np.uint64(np.uint32(i32[k])) & _LO32) | (np.uint64(np.uint32(i32[k + 1])) << _S32)


@njit(**INLINE)
def dcsg_base(buf):
    """Word offsets of the DCSG blob: (int64/float64 index, int32 index)."""
    i64 = buf[0]
    w = (i64[H_F64] >> 3) + i64[H_DCSG]
    return w, 2 * w


@njit(**INLINE)
def dcsg_vs0(buf):
    """First virtual shape of a DCSG primitive (NO_VSHAPE when the scene has none)."""
    i64 = buf[0]
    return i64[dcsg_base(buf)[0] + B_VS0]


@njit(**INLINE)
def _alternative(i32, f64, o_alt0, o_nalt, o_cum, node, h):
    """The alternative a node of hash h takes: lsystem's choice, draw(h) against the
    running probabilities (the last one on rounding)."""
    k = i32[o_alt0 + node]
    nalt = i32[o_nalt + node]
    if nalt > 1:
        u = _draw(h)
        last = k + nalt - 1
        while k < last and not f64[o_cum + k] > u:
            k += 1
    return k


@njit(**INLINE)
def _tables(i64, w, iw):
    """Start of each blob table in its view: int32 ones, then float64 ones."""
    return (iw + i64[w + B_NODE_ALT0], iw + i64[w + B_NODE_NALT], iw + i64[w + B_NODE_PRIM],
            iw + i64[w + B_NODE_STUB], iw + i64[w + B_ALT_C0], iw + i64[w + B_ALT_NC],
            iw + i64[w + B_CH_NODE], iw + i64[w + B_CH_J], iw + i64[w + B_PRIM_KIND],
            w + i64[w + B_NODE_BOX], w + i64[w + B_ALT_CUM], w + i64[w + B_CH_INV],
            w + i64[w + B_CH_ROT], w + i64[w + B_CH_BOX], w + i64[w + B_PRIM_PARAMS],
            w + i64[w + B_PRIM_INV])


@njit(**INLINE)
def _cache_tables(i64, w, iw):
    """Start of each expansion-cache table in its view (the records: int32 / float32)."""
    return (iw + i64[w + B_NODE_CACHE], iw + i64[w + B_CACHE_ROOT], iw + i64[w + B_CACHE_REC],
            iw + i64[w + B_ITEM_PRIM], iw + i64[w + B_ITEM_C0], iw + i64[w + B_ITEM_NC],
            iw + i64[w + B_CHAIN_J], w + i64[w + B_ITEM_INV])


@njit(**INLINE)
def _inverse_dir(d):
    """1/d, with 1e300 of the same sign for d = 0: the slab test needs no branch then
    (a ray parallel to a slab outside it gets a huge finite entry: a false positive
    that tbest culls, never a false negative)."""
    if d != 0.0:
        return 1.0 / d
    return -1e300 if math.copysign(1.0, d) < 0.0 else 1e300


@njit(**INLINE)
def _slabs(f64, b, ox, oy, oz, ix, iy, iz, tmin, tmax):
    """Entry distance into the box at f64[b:b+6] of the ray with inverse direction
    (ix, iy, iz) within (tmin, tmax), or inf. The exit is widened by 1e-12 relative
    (the rounding of (b - o) / d)."""
    a0 = (f64[b] - ox) * ix
    a1 = (f64[b + 3] - ox) * ix
    b0 = (f64[b + 1] - oy) * iy
    b1 = (f64[b + 4] - oy) * iy
    c0 = (f64[b + 2] - oz) * iz
    c1 = (f64[b + 5] - oz) * iz
    t0 = max(tmin, min(a0, a1), min(b0, b1), min(c0, c1))
    t1 = min(tmax, max(a0, a1), max(b0, b1), max(c0, c1))
    t1 = t1 * (1.0 + 1e-12) if t1 > 0.0 else t1 * (1.0 - 1e-12)
    return t0 if t0 <= t1 else math.inf


@njit(**INLINE)
def _scratch(s0):
    """Offsets of the ray scratch: float64 entries, uint64 entries (float64 / uint64
    index), then int32 indices of the nodes, edges, depths, path, best path, the
    cache-BVH stack, its float64 entry t's (float64 index), and the result."""
    fb = s0 // 2
    hb = fb + _E_F * STACK_ENTRIES
    nb = 2 * (hb + _E_U * STACK_ENTRIES)
    eb = nb + STACK_ENTRIES
    db = eb + STACK_ENTRIES
    pb = db + STACK_ENTRIES
    bp = pb + MAX_DEPTH
    kb = bp + MAX_DEPTH
    k2 = kb + CACHE_STACK
    k2 += k2 % 2
    rb = k2 + 2 * CACHE_STACK
    return fb, hb, nb, eb, db, pb, bp, kb, k2 // 2, rb


@njit(**INLINE)
def _keep_path(stack, pb, bp, d):
    """The edge path to the current node (depth d) becomes the closest hit's."""
    for q in range(1, d + 1):
        stack[bp + q] = stack[pb + q]


@njit(**INLINE)
def _organ_tables(i64, w, iw):
    """(first triangle, triangle count: int32 per organ; triangles: 9 float64 each)."""
    return iw + i64[w + B_ORG_T0], iw + i64[w + B_ORG_NT], w + i64[w + B_ORG_TRI]


@njit(**INLINE)
def _terminal_hit(i32, f64, o_pk, o_pp, o_org, p, m, ox, oy, oz, dx, dy, dz, tmin, tbest):
    """Nearest crossing in (tmin, tbest) of terminal primitive row p, the ray mapped
    into its frame by the 3x4 at f64[m:]: (t, local normal, not unit); t = inf if
    none. An organ is a triangle mesh (both sides; normal e1 x e2), any other kind
    an analytic primitive."""
    lx, ly, lz, ex, ey, ez = xform_ray(f64, m, ox, oy, oz, dx, dy, dz)
    pp = o_pp + 4 * p
    kind = i32[o_pk + p]
    if kind == ORGAN:
        o_t0, o_nt, o_tri = o_org
        g = np.int64(f64[pp])
        t = math.inf
        nx, ny, nz = 0.0, 0.0, 1.0
        t0 = i32[o_t0 + g]
        for k in range(t0, t0 + i32[o_nt + g]):
            q = o_tri + 9 * k
            ti, cx, cy, cz = _triangle(f64, q, lx, ly, lz, ex, ey, ez, tmin, min(t, tbest))
            if ti < t:
                t, nx, ny, nz = ti, cx, cy, cz
        return t, nx, ny, nz
    params = (f64[pp], f64[pp + 1], f64[pp + 2], f64[pp + 3])
    n, t0_, t1, t2, t3 = prim_hits(kind, params, lx, ly, lz, ex, ey, ez)
    for i in range(n):
        ti = (t0_, t1, t2, t3)[i]
        if ti > tmin and ti < tbest:
            _fc, _u, _v, nx, ny, nz = prim_surface(kind, params, lx + ti * ex, ly + ti * ey,
                                                   lz + ti * ez)
            return ti, nx, ny, nz
    return math.inf, 0.0, 0.0, 1.0


@njit(**INLINE)
def _triangle(f64, q, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Moller-Trumbore against the triangle at f64[q:q+9] (v0, v1, v2): (t, e1 x e2),
    t = inf outside (tmin, tmax) or on a miss."""
    ax, ay, az = f64[q], f64[q + 1], f64[q + 2]
    e1x, e1y, e1z = f64[q + 3] - ax, f64[q + 4] - ay, f64[q + 5] - az
    e2x, e2y, e2z = f64[q + 6] - ax, f64[q + 7] - ay, f64[q + 8] - az
    px, py, pz = cross(dx, dy, dz, e2x, e2y, e2z)
    det = e1x * px + e1y * py + e1z * pz
    if det == 0.0:
        return math.inf, 0.0, 0.0, 1.0
    inv = 1.0 / det
    sx, sy, sz = ox - ax, oy - ay, oz - az
    u = (sx * px + sy * py + sz * pz) * inv
    if u < 0.0 or u > 1.0:
        return math.inf, 0.0, 0.0, 1.0
    qx, qy, qz = cross(sx, sy, sz, e1x, e1y, e1z)
    v = (dx * qx + dy * qy + dz * qz) * inv
    if v < 0.0 or u + v > 1.0:
        return math.inf, 0.0, 0.0, 1.0
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    if not (t > tmin and t < tmax):
        return math.inf, 0.0, 0.0, 1.0
    nx, ny, nz = cross(e1x, e1y, e1z, e2x, e2y, e2z)
    return t, nx, ny, nz


@njit(**CORE)
def dcsg_closest_core(buf, stack, s0, graph, ox, oy, oz, dx, dy, dz, tmin, tmax, any_hit):
    """Closest hit of a prototype-space ray with DCSG `graph`, expanded lazily:
    (t, virtual shape id); (tmax, -1) on a miss. On a hit the normal (prototype
    space) and the stub's index in the scene's stub table (-1: none) are left for
    `dcsg_hit_surface`. any_hit: stop at the first hit (occlusion).

    Like a BVH node, a node holds its children's boxes in its own frame, so a
    child is entered (its ray transformed, pushed) only when the ray meets its box;
    the nearest child is expanded first. Entries carry only the ray: the hit's
    normal is rotated to the object by the edge path, once per ray."""
    i64, f32, i32, f64 = buf[:4]
    w, iw = dcsg_base(buf)
    (o_alt0, o_nalt, o_prim, o_stub, o_ac0, o_anc, o_chn, o_chj, o_pk,
     o_box, o_cum, o_cinv, o_crot, o_cbox, o_pp, o_pinv) = _tables(i64, w, iw)
    root = i32[iw + i64[w + B_GRAPH_ROOT] + graph]
    fs = as_float64(stack)
    us = as_uint64(stack)
    fb, hb, nb, eb, db, pb, bp, kb, kf, rb = _scratch(s0)
    o_ncache, o_croot, o_crec, o_ip, o_ic0, o_inc, o_chain, o_iinv = _cache_tables(i64, w, iw)
    o_istub = iw + i64[w + B_ITEM_STUB]
    o_org = _organ_tables(i64, w, iw)
    f32s = as_float32(stack)
    rf = rb // 2                       # result: normal (3 float64), stub (int32 at rb + 6), address
    t_root = _slabs(f64, o_box + 6 * root, ox, oy, oz, _inverse_dir(dx), _inverse_dir(dy),
                    _inverse_dir(dz), tmin, tmax)
    if t_root == math.inf:
        return tmax, -1
    fs[fb], fs[fb + 1], fs[fb + 2], fs[fb + 3], fs[fb + 4], fs[fb + 5] = ox, oy, oz, dx, dy, dz
    fs[fb + 6] = t_root
    us[hb] = _u64(i32, iw + i64[w + B_GRAPH_HASH] + 2 * graph)
    us[hb + 1] = np.uint64(0)
    stack[nb], stack[eb], stack[db] = root, -1, 0
    sp = 1
    tbest = tmax
    best_p = -1
    best_d = 0
    best_s = np.uint64(0)
    best_h = np.uint64(0)
    bnx, bny, bnz = 0.0, 0.0, 1.0
    while sp > 0:
        sp -= 1
        f = fb + _E_F * sp
        if fs[f + 6] >= tbest:
            continue
        node = stack[nb + sp]
        d = stack[db + sp]
        e = stack[eb + sp]
        stack[pb + d] = e                # ancestors' edges at 1..d-1 are still in place (DFS)
        h = us[hb + 2 * sp]
        stub = h if i32[o_stub + node] else us[hb + 2 * sp + 1]
        # copied out: the children are pushed over this very entry. Entries hold the
        # parent's ray; it enters the child's frame only now, past the tbest cull.
        rox, roy, roz, rdx, rdy, rdz = fs[f], fs[f + 1], fs[f + 2], fs[f + 3], fs[f + 4], fs[f + 5]
        if e >= 0:
            rox, roy, roz, rdx, rdy, rdz = xform_ray(f64, o_cinv + 12 * e, rox, roy, roz, rdx, rdy, rdz)
        ix, iy, iz = _inverse_dir(rdx), _inverse_dir(rdy), _inverse_dir(rdz)
        ci = i32[o_ncache + node]
        if ci >= 0:                      # an expanded subgraph: its BVH, in this node's frame
            sx, sy, sz, nxo, nyo, nzo = ray_slabs(rdx, rdy, rdz)
            rec = i32[o_croot + ci]
            ks = kb
            while True:
                b = o_crec + 32 * rec
                mk, lm, n0, n1, n2, n3 = slab4(f32, b, rox, roy, roz, sx, sy, sz, nxo, nyo, nzo,
                                                tmin, tbest)
                ml = mk & lm
                mi = mk & ~lm
                t_in = tbest
                while ml != 0:
                    k = ctz(ml)
                    ml &= ml - 1
                    a_ = i32[b + 24 + k]
                    for it in range(a_, a_ + i32[b + 28 + k]):
                        p = i32[o_ip + it]
                        m = o_iinv + 12 * it
                        ti, nx, ny, nz = _terminal_hit(i32, f64, o_pk, o_pp, o_org, p, m, rox, roy, roz,
                                                       rdx, rdy, rdz, tmin, tbest)
                        if ti < tbest:
                            tbest = ti
                            best_p = p
                            best_s = stub
                            hh = h               # the address: the chain of child indices
                            at = i32[o_istub + it]       # and the innermost stub along it
                            c0_ = i32[o_ic0 + it]
                            for q in range(c0_, c0_ + i32[o_inc + it]):
                                hh = _child_hash(hh, i32[o_chain + q])
                                if q - c0_ + 1 == at:
                                    best_s = hh
                            best_h = hh
                            best_d = d
                            _keep_path(stack, pb, bp, d)
                            bnx, bny, bnz = normal_through(f64, m, nx, ny, nz)
                if any_hit and best_p >= 0:
                    break
                if tbest < t_in:
                    mi = drop_far(mi, n0, n1, n2, n3, tbest)
                rec, ks = descend(stack, f32s, ks, i32, b, mi, n0, n1, n2, n3, tbest)
                if rec < 0:
                    rec, ks = pop_node(stack, f32s, ks, kb, tbest)
                    if rec < 0:
                        break
            if any_hit and best_p >= 0:
                break
            continue
        p = i32[o_prim + node]
        if p >= 0:                       # a terminal root (terminal children are tested below)
            t, nx, ny, nz = _terminal_hit(i32, f64, o_pk, o_pp, o_org, p, o_pinv + 12 * p,
                                          rox, roy, roz, rdx, rdy, rdz, tmin, tbest)
            if t < tbest:
                tbest = t
                best_p = p
                best_s = stub
                best_h = h
                best_d = d
                _keep_path(stack, pb, bp, d)
                bnx, bny, bnz = normal_through(f64, o_pinv + 12 * p, nx, ny, nz)
                if any_hit:
                    break
            continue
        k = _alternative(i32, f64, o_alt0, o_nalt, o_cum, node, h)
        base = sp
        c0 = i32[o_ac0 + k]
        for c in range(c0, c0 + i32[o_anc + k]):
            te = _slabs(f64, o_cbox + 6 * c, rox, roy, roz, ix, iy, iz, tmin, tbest)
            if te == math.inf:
                continue
            child = i32[o_chn + c]
            p = i32[o_prim + child]
            if p >= 0:                   # a terminal: test it now, with no push
                m = o_cinv + 12 * c
                ti, nx, ny, nz = _terminal_hit(i32, f64, o_pk, o_pp, o_org, p, m, rox, roy, roz,
                                               rdx, rdy, rdz, tmin, tbest)
                if ti < tbest:
                    tbest = ti
                    best_p = p
                    best_s = stub
                    best_h = _child_hash(h, i32[o_chj + c])
                    best_d = d
                    _keep_path(stack, pb, bp, d)
                    bnx, bny, bnz = normal_through(f64, m, nx, ny, nz)
                if any_hit and best_p >= 0:
                    break
                continue
            g = fb + _E_F * sp
            fs[g], fs[g + 1], fs[g + 2], fs[g + 3], fs[g + 4], fs[g + 5] = rox, roy, roz, rdx, rdy, rdz
            fs[g + 6] = te
            stack[nb + sp], stack[eb + sp], stack[db + sp] = child, c, d + 1
            us[hb + 2 * sp] = _child_hash(h, i32[o_chj + c])
            us[hb + 2 * sp + 1] = stub
            sp += 1
        if any_hit and best_p >= 0:
            break
        # nearest child on top: insertion sort of this level's entries, far first
        for i in range(base + 1, sp):
            j = i
            while j > base and fs[fb + _E_F * (j - 1) + 6] < fs[fb + _E_F * j + 6]:
                a_, b_ = fb + _E_F * (j - 1), fb + _E_F * j
                for q in range(_E_F):
                    fs[a_ + q], fs[b_ + q] = fs[b_ + q], fs[a_ + q]
                for q in (nb, eb):
                    stack[q + j - 1], stack[q + j] = stack[q + j], stack[q + j - 1]
                for q in range(2):
                    us[hb + 2 * (j - 1) + q], us[hb + 2 * j + q] = us[hb + 2 * j + q], us[hb + 2 * (j - 1) + q]
                j -= 1
    if best_p < 0:
        return tmax, -1
    for q in range(best_d, 0, -1):       # node -> object: R_c1 (R_c2 (... R_cd n))
        r = o_crot + 9 * stack[bp + q]
        bnx, bny, bnz = (f64[r] * bnx + f64[r + 1] * bny + f64[r + 2] * bnz,
                         f64[r + 3] * bnx + f64[r + 4] * bny + f64[r + 5] * bnz,
                         f64[r + 6] * bnx + f64[r + 7] * bny + f64[r + 8] * bnz)
    fs[rf], fs[rf + 1], fs[rf + 2] = unit(bnx, bny, bnz)
    us[rf + 4] = best_h
    stack[rb + 6] = _stub_index(i32, iw, i64[w + B_GRAPH_STUB], i64[w + B_STUB_ADDR], graph, best_s)
    return tbest, i64[w + B_VS0] + best_p


@njit(**INLINE)
def _stub_index(i32, iw, o_rows, o_addr, graph, addr):
    """Index of stub address `addr` in the scene's stub table (the graph's rows of it
    are sorted), -1 if none."""
    if addr == np.uint64(0):
        return -1
    lo = i32[iw + o_rows + 2 * graph]
    hi = lo + i32[iw + o_rows + 2 * graph + 1] - 1
    while lo <= hi:
        mid = (lo + hi) // 2
        v = _u64(i32, iw + o_addr + 2 * mid)
        if v == addr:
            return mid
        if v < addr:
            lo = mid + 1
        else:
            hi = mid - 1
    return -1


@njit(**INLINE)
def dcsg_hit_surface(stack, s0):
    """(stub index, nx, ny, nz, address) of the last DCSG hit `dcsg_closest_core` returned."""
    fs = as_float64(stack)
    rb = _scratch(s0)[-1]
    rf = rb // 2
    return stack[rb + 6], fs[rf], fs[rf + 1], fs[rf + 2], as_uint64(stack)[rf + 4]


# ---------------------------------------------------------------- stand-alone tracing

def dcsg_table(graphs):
    """A minimal trace-style buffer holding only the DCSG blob, so the same kernels
    run on it as on a Geometry (tests, the CLI, benchmarks) -> (buf views, prim_graph, stubs)."""
    blob, prim_graph, stubs = pack_blob(graphs, vs0=0)
    hdr = np.zeros(32, np.int64)
    hdr[H_F64] = 32 * 8
    hdr[H_DCSG] = 0
    from .bvh import aligned_empty
    raw = aligned_empty(hdr.nbytes + blob.nbytes, np.uint8)      # the records' vector loads
    raw[:hdr.nbytes] = hdr.view(np.uint8)
    raw[hdr.nbytes:] = blob.view(np.uint8)
    views = (raw.view(np.int64), raw.view(np.float32), raw.view(np.int32), raw.view(np.float64),
             features.marker(features.DCSG))
    return views, prim_graph, stubs


@njit(cache=True)
def _closest_batch(buf, origins, dirs, tmax, t_out, p_out, s_out, h_out, n_out):
    stack = np.empty(SCRATCH_WORDS + 2, np.int32)
    for i in range(origins.shape[0]):
        # typed, not literal, arguments: the traversal's signature (jit.typed)
        t, vs = dcsg_closest_core(buf, stack, typed(0), typed(0), origins[i, 0], origins[i, 1],
                                  origins[i, 2], dirs[i, 0], dirs[i, 1], dirs[i, 2], 0.0, tmax[i],
                                  typed(False))
        t_out[i] = t
        p_out[i] = vs
        s, n_out[i, 0], n_out[i, 1], n_out[i, 2], h_out[i] = dcsg_hit_surface(stack, 0)
        s_out[i] = s if vs >= 0 else -1


def trace_closest(graph, origins, dirs, tmax=math.inf):
    """Closest hits of object-space rays with one graph: (t, terminal primitive row,
    address, stub index into `stub_addresses(graph)` (-1: none), unit normal (n, 3));
    t = tmax and row -1 on a miss."""
    views, _pg, stubs = dcsg_table([graph])
    o = np.ascontiguousarray(origins, np.float64).reshape(-1, 3)
    d = np.ascontiguousarray(dirs, np.float64).reshape(-1, 3)
    if not (np.all(np.isfinite(o)) and np.all(np.isfinite(d))):
        raise SceneError("DCSG rays: non-finite origin or direction")
    n = o.shape[0]
    tm = np.broadcast_to(np.asarray(tmax, np.float64), (n,)).copy()
    t, p, s, nrm = np.empty(n), np.empty(n, np.int64), np.empty(n, np.int64), np.empty((n, 3))
    h = np.empty(n, np.uint64)
    _closest_batch(views, o, d, tm, t, p, s, h, nrm)
    return t, p, h, s, nrm


def stub_addresses(graph):
    """The graph's OL stub addresses, sorted: a hit's stub index points in here."""
    return _stub_addresses(graph)


# ---------------------------------------------------------------- area estimation (6.3)

def node_areas(graph):
    """Per node of the graph (its arrays' order): an area proxy of its subtree,
    the proposal by which area samples descend (expected over alternatives). Any
    positive proposal keeps the estimate unbiased; a good one keeps it quiet."""
    from .primitives import prim_area
    a = graph.arrays()
    ids = {id(n): i for i, n in enumerate(graph.nodes)}
    out = np.zeros(len(graph.nodes))
    done = np.zeros(len(graph.nodes), bool)

    def area(n):
        i = ids[id(n)]
        if done[i]:
            return out[i]
        if n.prim is not None:
            kind, params, xf, _ = n.prim
            local = graph.organs.area[int(params[0])] if kind == ORGAN else prim_area(kind, params)
            v = local * abs(np.linalg.det(xf[:, :3])) ** (2.0 / 3.0)
        else:
            v, prev = 0.0, 0.0
            for cum, children in n.alts:
                v += (cum - prev) * sum(area(c) for c, _, _ in children)
                prev = cum
        out[i], done[i] = v, True
        return v

    for n in reversed(graph.nodes):      # children were made before their parents
        area(n)
    del a
    return out


@njit(cache=True, parallel=True)
def _area_samples(buf, node_area, start, start_hash, rot0, inst_inv, det_inst, exclude_stubs,
                  res, n_s, seed, out_bin, out_val):
    """s samples over the subtree of node `start` (hash start_hash, object rotation
    rot0 (3, 3)): the sample's world area element, divided by s and its probability,
    into the octahedral bin of its normal. exclude_stubs: a sample that enters a
    nested stub counts 0 there (that stub is an OL of its own)."""
    i64, f32, i32, f64 = buf[:4]
    w, iw = dcsg_base(buf)
    (o_alt0, o_nalt, o_prim, o_stub, o_ac0, o_anc, o_chn, o_chj, o_pk,
     _o_box, o_cum, _o_cinv, o_crot, _o_cbox, o_pp, o_pinv) = _tables(i64, w, iw)
    o_org_t0, o_org_nt, o_org_tri = _organ_tables(i64, w, iw)
    o_org_cdf = w + i64[w + B_ORG_CDF]
    for k in prange(n_s):
        out_bin[k] = -1
        out_val[k] = 0.0
        state = stream_state(seed, k)
        node = start
        h = start_hash
        prob = 1.0
        # the object rotation of the current node, as scalars (no per-sample arrays)
        r00, r01, r02 = rot0[0, 0], rot0[0, 1], rot0[0, 2]
        r10, r11, r12 = rot0[1, 0], rot0[1, 1], rot0[1, 2]
        r20, r21, r22 = rot0[2, 0], rot0[2, 1], rot0[2, 2]
        alive = True
        while i32[o_prim + node] < 0:
            a = _alternative(i32, f64, o_alt0, o_nalt, o_cum, node, h)
            c0 = i32[o_ac0 + a]
            nc = i32[o_anc + a]
            total = 0.0
            for c in range(c0, c0 + nc):
                total += node_area[i32[o_chn + c]]
            if nc == 0 or not total > 0.0:
                alive = False
                break
            state, u = next_float(state)
            x = u * total
            pick = c0 + nc - 1
            acc = 0.0
            for c in range(c0, c0 + nc):
                acc += node_area[i32[o_chn + c]]
                if x < acc:
                    pick = c
                    break
            child = i32[o_chn + pick]
            prob *= node_area[child] / total
            if exclude_stubs and i32[o_stub + child]:
                alive = False
                break
            r = o_crot + 9 * pick
            c00, c01, c02 = f64[r], f64[r + 1], f64[r + 2]
            c10, c11, c12 = f64[r + 3], f64[r + 4], f64[r + 5]
            c20, c21, c22 = f64[r + 6], f64[r + 7], f64[r + 8]
            r00, r01, r02 = (r00 * c00 + r01 * c10 + r02 * c20, r00 * c01 + r01 * c11 + r02 * c21,
                             r00 * c02 + r01 * c12 + r02 * c22)
            r10, r11, r12 = (r10 * c00 + r11 * c10 + r12 * c20, r10 * c01 + r11 * c11 + r12 * c21,
                             r10 * c02 + r11 * c12 + r12 * c22)
            r20, r21, r22 = (r20 * c00 + r21 * c10 + r22 * c20, r20 * c01 + r21 * c11 + r22 * c21,
                             r20 * c02 + r21 * c12 + r22 * c22)
            h = _child_hash(h, i32[o_chj + pick])
            node = child
        if not alive or not prob > 0.0:
            continue
        p = i32[o_prim + node]
        kind = i32[o_pk + p]
        pp = o_pp + 4 * p
        params = (f64[pp], f64[pp + 1], f64[pp + 2], f64[pp + 3])
        state, u1 = next_float(state)
        state, u2 = next_float(state)
        state, u3 = next_float(state)
        if kind == ORGAN:
            # a triangle by its share of the organ's area, then e1 x e2 (twice its area)
            g = np.int64(params[0])
            t0 = i32[o_org_t0 + g]
            nt = i32[o_org_nt + g]
            j = t0 + nt - 1
            for tk in range(t0, t0 + nt):
                if u1 < f64[o_org_cdf + tk]:
                    j = tk
                    break
            pk = f64[o_org_cdf + j] - (f64[o_org_cdf + j - 1] if j > t0 else 0.0)
            if not pk > 0.0:
                continue
            qq = o_org_tri + 9 * j
            cx, cy, cz = cross(f64[qq + 3] - f64[qq], f64[qq + 4] - f64[qq + 1], f64[qq + 5] - f64[qq + 2],
                               f64[qq + 6] - f64[qq], f64[qq + 7] - f64[qq + 1], f64[qq + 8] - f64[qq + 2])
            nf = 0.5 / pk
        else:
            nf = prim_nfaces(kind)
            face = min(np.int64(u1 * nf), nf - 1)
            q = prim_point(kind, params, face, u2, u3)
            cx, cy, cz = cross(q[3], q[4], q[5], q[6], q[7], q[8])
        # local -> node: cof(P) c = det(P) P^-T c, P^-1 being the stored inverse
        m = o_pinv + 12 * p
        det_inv = (f64[m] * (f64[m + 5] * f64[m + 10] - f64[m + 6] * f64[m + 9])
                   - f64[m + 1] * (f64[m + 4] * f64[m + 10] - f64[m + 6] * f64[m + 8])
                   + f64[m + 2] * (f64[m + 4] * f64[m + 9] - f64[m + 5] * f64[m + 8]))
        nx, ny, nz = normal_through(f64, m, cx, cy, cz)
        sc = 1.0 / abs(det_inv)
        ox = (r00 * nx + r01 * ny + r02 * nz) * sc
        oy = (r10 * nx + r11 * ny + r12 * nz) * sc
        oz = (r20 * nx + r21 * ny + r22 * nz) * sc
        wx, wy, wz = apply_transposed(inst_inv, ox, oy, oz)
        ln = math.sqrt(wx * wx + wy * wy + wz * wz) * det_inst
        if not ln > 0.0:
            continue
        s_, t_ = octa_encode(wx, wy, wz)
        bx = min(max(np.int64(s_ * res), 0), res - 1)
        by = min(max(np.int64(t_ * res), 0), res - 1)
        out_bin[k] = by * res + bx
        out_val[k] = nf * ln / (n_s * prob)


def estimate_graph_areas(views, graph, node_area, start, start_hash, rot0, inst_inv, res, samples,
                         seed=0, exclude_stubs=True):
    """(area per bin, variance per bin) of one subtree of a graph under an instance:
    `start` (global node id), its hash and object rotation; inst_inv the instance's
    3x4 inverse. Unbiased for any proposal; samples that enter nested stubs count 0."""
    s = int(samples)
    R = int(res)
    b = np.empty(s, np.int64)
    v = np.empty(s)
    inv = np.ascontiguousarray(inst_inv, np.float64)[:3]
    det_inst = 1.0 / abs(float(np.linalg.det(inv[:, :3])))
    _area_samples(views, np.ascontiguousarray(node_area, np.float64), int(start), np.uint64(start_hash),
                  np.ascontiguousarray(rot0, np.float64), inv, det_inst, bool(exclude_stubs), R, s,
                  np.uint64(seed), b, v)
    ok = b >= 0
    area = np.bincount(b[ok], weights=v[ok], minlength=R * R).astype(np.float64)
    sq = np.bincount(b[ok], weights=v[ok] ** 2, minlength=R * R).astype(np.float64)
    var = np.maximum(sq - area * area / s, 0.0) * s / max(s - 1, 1)
    return area, var
