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
from collections import namedtuple

import numpy as np

from ..lsystem.grammar import MASK, child_hash, draw, splitmix64
from ..lsystem import derivation
from .primitives import KIND_IDS
from ..core.scene import SceneError
from ..lsystem.turtle import TurtleState, to_primitives

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
        self.root_hash = splitmix64(grammar.seed & MASK)
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
            for c, to_parent, j in chosen_children(n, h):
                walk(c, m @ to_parent, child_hash(h, j), stub)

        walk(self.root, np.eye(4), self.root_hash, 0)
        cols = list(zip(*out)) if out else [()] * 6
        return Flattened(np.array(cols[0], np.int64), np.array(cols[1], np.float64).reshape(-1, 4),
                         np.array(cols[2], np.float64).reshape(-1, 3, 4), np.array(cols[3], np.int64),
                         np.array(cols[4], np.uint64), np.array(cols[5], np.uint64))


Flattened = namedtuple("Flattened", "kind params transform material address stub")


def chosen_children(n, h):
    """The children of node n under the alternative its hash h chooses (as the kernels do)."""
    if not n.alts:
        return ()
    k = 0
    if len(n.alts) > 1:
        u = draw(h)
        while k < len(n.alts) - 1 and not n.alts[k][0] > u:
            k += 1
    return n.alts[k][1]


def _box_through(lo, hi, m):
    c = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    w = c @ m[:3].T
    return w.min(axis=0), w.max(axis=0)
