"""Directed cyclic scene graphs (DCSG) for context-free L-systems (thesis 4.2.2-4.4).

A context-free pL-system (engine/lsystem.py) is translated into a graph
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
U = -Y, engine/turtle.py). A child starting at turtle frame E (4x4, columns
L U H p, in parent coordinates) maps to its parent by E @ M0 (M0 = the start
frame, its own inverse). A node also has an *exit*: the turtle frame and
width/material after its whole expansion, which places its right siblings.
A grammar whose alternatives for one node leave the turtle in different
exits cannot be a DCSG (a later sibling's frame would depend on the choice);
like a context-sensitive grammar it is refused with `DCSGUnsupported`, and
the caller derives the string and instances its primitives instead.
"""
import math
from collections import namedtuple

import numpy as np
from numba import njit

from . import lsystem as LS
from .primitives import KIND_IDS, prim_hits, prim_surface
from .scene import SceneError
from .turtle import TurtleState, to_primitives

# The turtle's start frame: columns L = -X, U = -Y, H = +Z.
M0 = np.diag([-1.0, -1.0, 1.0, 1.0])
# Exits of alternatives must agree to this (relative to the node's extent).
EXIT_TOLERANCE = 1e-9
_CORNERS = np.array([[x, y, z, 1.0] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])


class DCSGUnsupported(SceneError):
    """The grammar cannot be a DCSG (context, or choice-dependent exits); derive it instead."""


class _Node:
    __slots__ = ("key", "alts", "prim", "exit", "state", "lo", "hi", "n_prims", "depth", "stub")

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
    "child_inv",                     # float64[C, 3, 4]: parent frame -> child frame
    "child_rot",                     # float64[C, 3, 3]: child -> parent rotation (normals)
    "prim_kind", "prim_params",      # int64[P], float64[P, 4]
    "prim_inv",                      # float64[P, 3, 4]: node frame -> primitive
    "prim_material",                 # int64[P]
    "root", "root_hash", "stack_size",
])


class DCSG:
    """The graph of one context-free grammar at a derivation length (see the module docstring)."""

    def __init__(self, grammar, steps=None, angle=None, width=None):
        if not grammar.is_context_free:
            raise DCSGUnsupported(f"{grammar.source_name}: a context-sensitive grammar cannot be a "
                                  "cyclic scene graph (its context crosses branches); it is derived "
                                  "to a string and its primitives instanced instead")
        self.grammar = grammar
        self.steps = grammar.derivation_length if steps is None else int(steps)
        if self.steps is None:
            self.steps = LS.check_termination(grammar)
            if self.steps is None:
                raise DCSGUnsupported(f"{grammar.source_name}: give a derivation length")
        self.angle = grammar.angle if angle is None else float(angle)
        self.width = grammar.width if width is None else float(width)
        self._stubs = {s.symbol: s.levels for s in grammar.ol_stubs}
        self.nodes = []
        self._memo = {}
        # the axiom is the successor of a virtual root of hash splitmix64(seed), so
        # axiom module i gets lsystem.root_hash(seed, i) as in derive()
        self.root = self._rule(None, self.steps + 1, (self.width, None, 0), [list(grammar.axiom)])
        self.root_hash = LS.splitmix64(grammar.seed & LS.MASK)

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
        prims = to_primitives(ts.geometry())
        if prims:
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

    # ------------------------------------------------------------ reading

    @property
    def implicit_primitives(self):
        """Primitives the graph stands for (expected value where choices are stochastic)."""
        v = self.root.n_prims
        return int(round(v)) if not self.grammar.is_stochastic else float(v)

    def stats(self):
        a = self.arrays()
        nbytes = sum(x.nbytes for x in a if isinstance(x, np.ndarray))
        return {"dcsg_nodes": len(self.nodes),
                "alternatives": int(a.alt_cum.shape[0]), "edges": int(a.child_node.shape[0]),
                "terminal_primitives": int(a.prim_kind.shape[0]),
                "primitives": self.implicit_primitives, "depth": int(self.root.depth),
                "bytes": int(nbytes)}

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
        ch_node, ch_j, ch_inv, ch_rot = [], [], [], []
        p_kind, p_params, p_inv, p_mat = [], [], [], []
        widest = 1
        for i, n in enumerate(self.nodes):
            node_lo[i], node_hi[i] = n.lo, n.hi
            node_stub[i] = n.stub
            node_alt0[i], node_nalt[i] = len(alt_cum), len(n.alts)
            for cum, children in n.alts:
                alt_cum.append(cum)
                alt_c0.append(len(ch_node))
                alt_nc.append(len(children))
                widest = max(widest, len(children))
                for c, to_parent, j in children:
                    ch_node.append(ids[id(c)])
                    ch_j.append(j)
                    ch_inv.append(np.linalg.inv(to_parent)[:3])
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
            np.array(p_kind, np.int64), np.array(p_params, np.float64).reshape(-1, 4),
            np.array(p_inv, np.float64).reshape(-1, 3, 4), np.array(p_mat, np.int64),
            ids[id(self.root)], np.uint64(self.root_hash),
            # DFS: each level leaves at most (children - 1) siblings on the stack
            (widest) * (self.root.depth + 2) + 1)
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
            k = 0
            if len(n.alts) > 1:
                u = LS.draw(h)
                while k < len(n.alts) - 1 and not n.alts[k][0] > u:
                    k += 1
            for c, to_parent, j in n.alts[k][1]:
                walk(c, m @ to_parent, LS.child_hash(h, j), stub)

        walk(self.root, np.eye(4), self.root_hash, 0)
        cols = list(zip(*out)) if out else [()] * 6
        return Flattened(np.array(cols[0], np.int64), np.array(cols[1], np.float64).reshape(-1, 4),
                         np.array(cols[2], np.float64).reshape(-1, 3, 4), np.array(cols[3], np.int64),
                         np.array(cols[4], np.uint64), np.array(cols[5], np.uint64))


Flattened = namedtuple("Flattened", "kind params transform material address stub")


def _box_through(lo, hi, m):
    c = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    w = c @ m[:3].T
    return w.min(axis=0), w.max(axis=0)


# ---------------------------------------------------------------- ray kernels
# uint64 arithmetic with uint64 constants only: numba turns uint64 op int64 into float64.

_GOLD = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_DRAW = np.uint64(0xD1B54A32D192ED03)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)


@njit(cache=True)
def _splitmix64(x):
    z = x + _GOLD
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@njit(cache=True)
def _child_hash(h, j):
    return _splitmix64(h ^ (np.uint64(j + 1) * _GOLD))


@njit(cache=True)
def _draw(h):
    return float(_splitmix64(h ^ _DRAW) >> _S11) * (2.0 ** -53)


@njit(cache=True)
def _box_entry(lo, hi, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Entry distance of the ray into [lo, hi] within (tmin, tmax), or inf."""
    t0, t1 = tmin, tmax
    o = (ox, oy, oz)
    d = (dx, dy, dz)
    for k in range(3):
        if d[k] != 0.0:
            inv = 1.0 / d[k]
            a = (lo[k] - o[k]) * inv
            b = (hi[k] - o[k]) * inv
            if a > b:
                a, b = b, a
            t0 = max(t0, a)
            t1 = min(t1, b * (1.0 + 1e-12))
        elif o[k] < lo[k] or o[k] > hi[k]:
            return math.inf
    return t0 if t0 <= t1 else math.inf


@njit(cache=True)
def _first_prim_hit(a, p, ox, oy, oz, dx, dy, dz, tmin, tmax):
    m = a.prim_inv[p]
    lx = m[0, 0] * ox + m[0, 1] * oy + m[0, 2] * oz + m[0, 3]
    ly = m[1, 0] * ox + m[1, 1] * oy + m[1, 2] * oz + m[1, 3]
    lz = m[2, 0] * ox + m[2, 1] * oy + m[2, 2] * oz + m[2, 3]
    ex = m[0, 0] * dx + m[0, 1] * dy + m[0, 2] * dz
    ey = m[1, 0] * dx + m[1, 1] * dy + m[1, 2] * dz
    ez = m[2, 0] * dx + m[2, 1] * dy + m[2, 2] * dz
    n, t0, t1, t2, t3 = prim_hits(a.prim_kind[p], a.prim_params[p], lx, ly, lz, ex, ey, ez)
    for i in range(n):
        t = (t0, t1, t2, t3)[i]
        if t > tmin and t < tmax:
            return t, lx + t * ex, ly + t * ey, lz + t * ez
    return math.inf, 0.0, 0.0, 0.0


@njit(cache=True)
def dcsg_closest(a, ox, oy, oz, dx, dy, dz, tmin, tmax, fs, ns, hs, any_hit):
    """Closest hit of an object-space ray with the graph, expanded lazily.

    fs (stack_size, 16) float64, ns (stack_size,) int64, hs (stack_size, 2)
    uint64 are the caller's scratch stack. Returns (t, primitive row, address,
    stub address, nx, ny, nz (object-space unit normal)); t = tmax and row = -1
    on a miss. any_hit: return at the first hit (occlusion)."""
    sp = 0
    t_root = _box_entry(a.node_lo[a.root], a.node_hi[a.root], ox, oy, oz, dx, dy, dz, tmin, tmax)
    if t_root == math.inf:
        return tmax, -1, np.uint64(0), np.uint64(0), 0.0, 0.0, 1.0
    ns[0] = a.root
    hs[0, 0] = a.root_hash
    hs[0, 1] = np.uint64(0)
    f = fs[0]
    f[0], f[1], f[2], f[3], f[4], f[5] = ox, oy, oz, dx, dy, dz
    for k in range(9):
        f[6 + k] = 1.0 if k % 4 == 0 else 0.0
    f[15] = t_root
    sp = 1
    tbest = tmax
    best_p = -1
    best_h = np.uint64(0)
    best_s = np.uint64(0)
    bnx, bny, bnz = 0.0, 0.0, 1.0
    while sp > 0:
        sp -= 1
        f = fs[sp]
        if f[15] >= tbest:
            continue
        node = ns[sp]
        h = hs[sp, 0]
        stub = hs[sp, 1]
        if a.node_stub[node]:
            stub = h
        # copied out: the children are pushed over this very row
        rox, roy, roz, rdx, rdy, rdz = f[0], f[1], f[2], f[3], f[4], f[5]
        R = (f[6], f[7], f[8], f[9], f[10], f[11], f[12], f[13], f[14])
        p = a.node_prim[node]
        if p >= 0:
            t, lx, ly, lz = _first_prim_hit(a, p, rox, roy, roz, rdx, rdy, rdz, tmin, tbest)
            if t < tbest:
                tbest = t
                best_p = p
                best_h = h
                best_s = stub
                _fc, _u, _v, nx, ny, nz = prim_surface(a.prim_kind[p], a.prim_params[p], lx, ly, lz)
                m = a.prim_inv[p]
                # prim -> node by the inverse-transpose, then node -> object by the rotation
                qx = m[0, 0] * nx + m[1, 0] * ny + m[2, 0] * nz
                qy = m[0, 1] * nx + m[1, 1] * ny + m[2, 1] * nz
                qz = m[0, 2] * nx + m[1, 2] * ny + m[2, 2] * nz
                bnx = R[0] * qx + R[1] * qy + R[2] * qz
                bny = R[3] * qx + R[4] * qy + R[5] * qz
                bnz = R[6] * qx + R[7] * qy + R[8] * qz
                ln = math.sqrt(bnx * bnx + bny * bny + bnz * bnz)
                if ln > 0.0:
                    bnx, bny, bnz = bnx / ln, bny / ln, bnz / ln
                if any_hit:
                    break
            continue
        k = a.node_alt0[node]
        nalt = a.node_nalt[node]
        if nalt > 1:
            u = _draw(h)
            last = k + nalt - 1
            while k < last and not a.alt_cum[k] > u:
                k += 1
        base = sp
        for c in range(a.alt_child0[k], a.alt_child0[k] + a.alt_nchild[k]):
            child = a.child_node[c]
            m = a.child_inv[c]
            cox = m[0, 0] * rox + m[0, 1] * roy + m[0, 2] * roz + m[0, 3]
            coy = m[1, 0] * rox + m[1, 1] * roy + m[1, 2] * roz + m[1, 3]
            coz = m[2, 0] * rox + m[2, 1] * roy + m[2, 2] * roz + m[2, 3]
            cdx = m[0, 0] * rdx + m[0, 1] * rdy + m[0, 2] * rdz
            cdy = m[1, 0] * rdx + m[1, 1] * rdy + m[1, 2] * rdz
            cdz = m[2, 0] * rdx + m[2, 1] * rdy + m[2, 2] * rdz
            te = _box_entry(a.node_lo[child], a.node_hi[child], cox, coy, coz, cdx, cdy, cdz,
                            tmin, tbest)
            if te == math.inf:
                continue
            g = fs[sp]
            g[0], g[1], g[2], g[3], g[4], g[5] = cox, coy, coz, cdx, cdy, cdz
            r = a.child_rot[c]
            for i in range(3):          # object <- child: R_parent @ R_child
                for jj in range(3):
                    g[6 + 3 * i + jj] = (R[3 * i] * r[0, jj] + R[3 * i + 1] * r[1, jj]
                                         + R[3 * i + 2] * r[2, jj])
            g[15] = te
            ns[sp] = child
            hs[sp, 0] = _child_hash(h, a.child_j[c])
            hs[sp, 1] = stub
            sp += 1
        # nearest child on top: insertion sort of this level's entries by entry distance, far first
        for i in range(base + 1, sp):
            j = i
            while j > base and fs[j - 1, 15] < fs[j, 15]:
                for q in range(16):
                    fs[j - 1, q], fs[j, q] = fs[j, q], fs[j - 1, q]
                ns[j - 1], ns[j] = ns[j], ns[j - 1]
                for q in range(2):
                    hs[j - 1, q], hs[j, q] = hs[j, q], hs[j - 1, q]
                j -= 1
    return tbest, best_p, best_h, best_s, bnx, bny, bnz


@njit(cache=True)
def _closest_batch(a, origins, dirs, tmax, t_out, p_out, h_out, s_out, n_out):
    fs = np.empty((a.stack_size, 16))
    ns = np.empty(a.stack_size, np.int64)
    hs = np.empty((a.stack_size, 2), np.uint64)
    for i in range(origins.shape[0]):
        t, p, h, s, nx, ny, nz = dcsg_closest(a, origins[i, 0], origins[i, 1], origins[i, 2],
                                              dirs[i, 0], dirs[i, 1], dirs[i, 2], 0.0, tmax[i],
                                              fs, ns, hs, False)
        t_out[i], p_out[i], h_out[i], s_out[i] = t, p, h, s
        n_out[i, 0], n_out[i, 1], n_out[i, 2] = nx, ny, nz


def trace_closest(dcsg, origins, dirs, tmax=math.inf):
    """Closest hits of object-space rays: (t, primitive row, address, stub, normal (n, 3));
    t = tmax and row -1 on a miss."""
    a = dcsg.arrays()
    o = np.ascontiguousarray(origins, np.float64).reshape(-1, 3)
    d = np.ascontiguousarray(dirs, np.float64).reshape(-1, 3)
    if not (np.all(np.isfinite(o)) and np.all(np.isfinite(d))):
        raise SceneError("DCSG rays: non-finite origin or direction")
    n = o.shape[0]
    tm = np.broadcast_to(np.asarray(tmax, np.float64), (n,)).copy()
    t = np.empty(n)
    p = np.empty(n, np.int64)
    h = np.empty(n, np.uint64)
    s = np.empty(n, np.uint64)
    nrm = np.empty((n, 3))
    _closest_batch(a, o, d, tm, t, p, h, s, nrm)
    return t, p, h, s, nrm
