"""Binned-SAH bounding volume hierarchy over axis-aligned item boxes (one level).

`build_bvh(lo, hi)` returns the flat layout shared by both levels of the
scene (docs/architecture.md):

    node_min[N,3], node_max[N,3]  float32, rounded outward (conservative)
    node_a[N], node_count[N]      int32; count > 0: leaf with items[a:a+count],
                                  count == 0: interior with children i+1 and a
    items[n]                      int32 item ids

Nodes are in depth-first order, so the left child of node i is i+1 and the
whole left subtree precedes the right child. An empty input gives a single
node with an empty box (min = +inf, max = -inf, count 0) that no ray enters.

`pack_bvh` converts that layout into the traversal layout used by
engine/geometry/raycast.py: the binary tree is collapsed into 4-wide records that hold
the boxes of up to four children (two cache lines), which halves the number
of dependent steps a ray takes.
"""
import numpy as np
from numba import njit

N_BINS = 16
MAX_LEAF = 4
# Hard bound on the depth of a leaf below the root. A SAH split is taken only
# if both sides can still be finished by median halving within the bound, so
# pathological inputs cannot make trees deeper than the traversal stacks
# allow (see STACK_BUDGET).
MAX_DEPTH = 30
# SAH: cost of visiting a node relative to intersecting one item.
C_TRAV = 1.0
REC_WORDS = 32    # words (float32 / int32) per packed 4-wide record: two cache lines
PACK_LEAF = 4     # subtrees with this many items or fewer become one packed leaf (one packet)
# Stack entries one BVH level may need. Packing keeps every traversal within
# it (the binary depth bound MAX_DEPTH <= STACK_BUDGET makes that possible),
# so two levels fit a 128-word stack (two words per entry).
STACK_BUDGET = 32


@njit(cache=True, inline="always")
def _half_area(x0, y0, z0, x1, y1, z1):
    ex, ey, ez = x1 - x0, y1 - y0, z1 - z0
    return ex * ey + ey * ez + ez * ex


@njit(cache=True, inline="always")
def _bin_of(c, cmin, k, n_bins):
    b = int((c - cmin) * k)
    if b < 0:
        return 0
    if b >= n_bins:
        return n_bins - 1
    return b


@njit(cache=True, inline="always")
def _halving_levels(count, max_leaf):
    """Levels median halving needs to turn `count` items into leaves."""
    lv = 0
    while count > max_leaf:
        count = (count + 1) // 2
        lv += 1
    return lv


@njit(cache=True, inline="always")
def _node_bounds(idx, start, end, lo, hi, cen):
    """Box of the items idx[start:end] and box of their centroids (12 scalars)."""
    bx0 = by0 = bz0 = np.inf
    bx1 = by1 = bz1 = -np.inf
    cx0 = cy0 = cz0 = np.inf
    cx1 = cy1 = cz1 = -np.inf
    for j in range(start, end):
        it = idx[j]
        bx0 = min(bx0, lo[it, 0])
        by0 = min(by0, lo[it, 1])
        bz0 = min(bz0, lo[it, 2])
        bx1 = max(bx1, hi[it, 0])
        by1 = max(by1, hi[it, 1])
        bz1 = max(bz1, hi[it, 2])
        cx0 = min(cx0, cen[it, 0])
        cy0 = min(cy0, cen[it, 1])
        cz0 = min(cz0, cen[it, 2])
        cx1 = max(cx1, cen[it, 0])
        cy1 = max(cy1, cen[it, 1])
        cz1 = max(cz1, cen[it, 2])
    return bx0, by0, bz0, bx1, by1, bz1, cx0, cy0, cz0, cx1, cy1, cz1


@njit(cache=True, inline="always")
def _best_sah_split(idx, start, end, lo, hi, cen, cmin, cext, depth, max_leaf, n_bins,
                    bcnt, blo, bhi, right_area):
    """Binned SAH over the three axes -> (cost, axis (-1: none), split bin, bin scale per axis).
    Splits that would push a subtree past MAX_DEPTH are not considered."""
    count = end - start
    best_cost = np.inf
    best_axis = -1
    best_split = 0
    # ks[ax] == 0 marks an axis that cannot be binned (flat or so
    # thin that the bin scale overflows)
    ks = np.zeros(3)
    if cext[0] > 0.0 or cext[1] > 0.0 or cext[2] > 0.0:
        bcnt[:, :] = 0
        blo[:, :, :] = np.inf
        bhi[:, :, :] = -np.inf
        for ax in range(3):
            if cext[ax] > 0.0:
                kk = n_bins * (1.0 - 1e-9) / cext[ax]
                if kk < np.inf:
                    ks[ax] = kk
        for j in range(start, end):
            it = idx[j]
            for ax in range(3):
                if ks[ax] > 0.0:
                    b = _bin_of(cen[it, ax], cmin[ax], ks[ax], n_bins)
                    bcnt[ax, b] += 1
                    for k in range(3):
                        if lo[it, k] < blo[ax, b, k]:
                            blo[ax, b, k] = lo[it, k]
                        if hi[it, k] > bhi[ax, b, k]:
                            bhi[ax, b, k] = hi[it, k]
        for ax in range(3):
            if ks[ax] == 0.0:
                continue
            # sweep from the right: area of bins b..n_bins-1
            x0 = y0 = z0 = np.inf
            x1 = y1 = z1 = -np.inf
            for b in range(n_bins - 1, 0, -1):
                if bcnt[ax, b] > 0:
                    x0 = min(x0, blo[ax, b, 0])
                    y0 = min(y0, blo[ax, b, 1])
                    z0 = min(z0, blo[ax, b, 2])
                    x1 = max(x1, bhi[ax, b, 0])
                    y1 = max(y1, bhi[ax, b, 1])
                    z1 = max(z1, bhi[ax, b, 2])
                right_area[b] = _half_area(x0, y0, z0, x1, y1, z1) if x1 >= x0 else 0.0
            # sweep from the left, evaluating the split before bin b
            x0 = y0 = z0 = np.inf
            x1 = y1 = z1 = -np.inf
            nl = 0
            for b in range(1, n_bins):
                if bcnt[ax, b - 1] > 0:
                    x0 = min(x0, blo[ax, b - 1, 0])
                    y0 = min(y0, blo[ax, b - 1, 1])
                    z0 = min(z0, blo[ax, b - 1, 2])
                    x1 = max(x1, bhi[ax, b - 1, 0])
                    y1 = max(y1, bhi[ax, b - 1, 1])
                    z1 = max(z1, bhi[ax, b - 1, 2])
                nl += bcnt[ax, b - 1]
                nr = count - nl
                if nl == 0 or nr == 0:
                    continue
                if depth + 1 + _halving_levels(max(nl, nr), max_leaf) > MAX_DEPTH:
                    continue
                cost = nl * _half_area(x0, y0, z0, x1, y1, z1) + nr * right_area[b]
                if cost < best_cost:
                    best_cost = cost
                    best_axis = ax
                    best_split = b
    return best_cost, best_axis, best_split, ks


@njit(cache=True, inline="always")
def _partition(idx, start, end, cen, ax, c0, k, n_bins, split):
    """Reorders idx[start:end] so items of bins < split come first -> the first of the rest
    (the same bin formula as the binning pass)."""
    l = start
    r = end - 1
    while l <= r:
        if _bin_of(cen[idx[l], ax], c0, k, n_bins) < split:
            l += 1
        else:
            tmp = idx[l]
            idx[l] = idx[r]
            idx[r] = tmp
            r -= 1
    return l


@njit(cache=True, inline="always")
def _median_split(idx, start, end, cen, cext):
    """Depth-limited fallback: object median along the widest centroid axis -> mid.
    When all centroids coincide any halving is as good as another."""
    count = end - start
    mid = (start + end + 1) // 2
    if cext[0] > 0.0 or cext[1] > 0.0 or cext[2] > 0.0:
        ax = 0
        if cext[1] > cext[ax]:
            ax = 1
        if cext[2] > cext[ax]:
            ax = 2
        if cext[ax] > 0.0:
            keys = np.empty(count)
            for j in range(count):
                keys[j] = cen[idx[start + j], ax]
            order = np.argsort(keys)
            sub = idx[start:end].copy()
            for j in range(count):
                idx[start + j] = sub[order[j]]
    return mid


@njit(cache=True)
def _build(lo, hi, max_leaf, n_bins, c_trav):
    n = lo.shape[0]
    cap = max(2 * n - 1, 1)
    nmin = np.empty((cap, 3))
    nmax = np.empty((cap, 3))
    na = np.zeros(cap, np.int32)
    nc = np.zeros(cap, np.int32)
    idx = np.arange(n).astype(np.int32)
    if n == 0:
        nmin[0, :] = np.inf
        nmax[0, :] = -np.inf
        return nmin, nmax, na, nc, idx, 1, 0

    cen = np.empty((n, 3))
    for i in range(n):
        for k in range(3):
            cen[i, k] = 0.5 * (lo[i, k] + hi[i, k])

    stack_cap = 2 * MAX_DEPTH + 8
    s_start = np.empty(stack_cap, np.int64)
    s_end = np.empty(stack_cap, np.int64)
    s_parent = np.empty(stack_cap, np.int64)
    s_depth = np.empty(stack_cap, np.int64)
    sp = 0
    s_start[0] = 0
    s_end[0] = n
    s_parent[0] = -1
    s_depth[0] = 0
    sp = 1

    bcnt = np.zeros((3, n_bins), np.int64)
    blo = np.empty((3, n_bins, 3))
    bhi = np.empty((3, n_bins, 3))
    right_area = np.empty(n_bins)
    nn = 0
    max_depth = 0

    while sp > 0:
        sp -= 1
        start = s_start[sp]
        end = s_end[sp]
        parent = s_parent[sp]
        depth = s_depth[sp]
        if depth > max_depth:
            max_depth = depth
        i = nn
        nn += 1
        if parent >= 0:
            na[parent] = i

        bx0, by0, bz0, bx1, by1, bz1, cx0, cy0, cz0, cx1, cy1, cz1 = _node_bounds(
            idx, start, end, lo, hi, cen)
        nmin[i, 0], nmin[i, 1], nmin[i, 2] = bx0, by0, bz0
        nmax[i, 0], nmax[i, 1], nmax[i, 2] = bx1, by1, bz1
        count = end - start

        if count <= 1:
            na[i] = start
            nc[i] = count
            continue

        cmin = (cx0, cy0, cz0)
        cext = (cx1 - cx0, cy1 - cy0, cz1 - cz0)
        best_cost, best_axis, best_split, ks = _best_sah_split(
            idx, start, end, lo, hi, cen, cmin, cext, depth, max_leaf, n_bins,
            bcnt, blo, bhi, right_area)
        area = _half_area(bx0, by0, bz0, bx1, by1, bz1)
        if best_axis >= 0:
            split_cost = c_trav * area + best_cost
            if count <= max_leaf and count * area <= split_cost:
                na[i] = start
                nc[i] = count
                continue
            mid = _partition(idx, start, end, cen, best_axis, cmin[best_axis], ks[best_axis], n_bins,
                             best_split)
        else:
            if count <= max_leaf:
                na[i] = start
                nc[i] = count
                continue
            mid = _median_split(idx, start, end, cen, cext)

        nc[i] = 0
        s_start[sp] = mid
        s_end[sp] = end
        s_parent[sp] = i
        s_depth[sp] = depth + 1
        sp += 1
        s_start[sp] = start
        s_end[sp] = mid
        s_parent[sp] = -1
        s_depth[sp] = depth + 1
        sp += 1

    return nmin[:nn], nmax[:nn], na[:nn], nc[:nn], idx, nn, max_depth


def round_down_f32(x):
    """float64 -> float32 rounded toward -inf (so boxes stay conservative)."""
    x = np.asarray(x, dtype=np.float64)
    with np.errstate(over="ignore"):          # beyond float32 range: +-inf is conservative
        f = x.astype(np.float32)
    low = f.astype(np.float64) > x
    return np.where(low, np.nextafter(f, np.float32(-np.inf)), f).astype(np.float32)


def round_up_f32(x):
    """float64 -> float32 rounded toward +inf."""
    x = np.asarray(x, dtype=np.float64)
    with np.errstate(over="ignore"):
        f = x.astype(np.float32)
    high = f.astype(np.float64) < x
    return np.where(high, np.nextafter(f, np.float32(np.inf)), f).astype(np.float32)


class BVH:
    """Flat BVH arrays (see module docstring) plus the tree depth."""
    __slots__ = ("node_min", "node_max", "node_a", "node_count", "items", "depth")

    def __init__(self, node_min, node_max, node_a, node_count, items, depth):
        self.node_min = node_min
        self.node_max = node_max
        self.node_a = node_a
        self.node_count = node_count
        self.items = items
        self.depth = depth

    @property
    def n_nodes(self):
        return self.node_a.shape[0]


def build_bvh(lo, hi, max_leaf=MAX_LEAF, n_bins=N_BINS, c_trav=C_TRAV):
    """Binned-SAH BVH over boxes lo[n,3] .. hi[n,3] (float64, finite)."""
    lo = np.ascontiguousarray(lo, dtype=np.float64).reshape(-1, 3)
    hi = np.ascontiguousarray(hi, dtype=np.float64).reshape(-1, 3)
    if lo.shape != hi.shape:
        raise ValueError("build_bvh: lo and hi differ in shape")
    if not (2 <= n_bins <= 256):
        raise ValueError("build_bvh: n_bins out of range")
    nmin, nmax, na, nc, idx, _, depth = _build(lo, hi, int(max(1, max_leaf)), int(n_bins),
                                             float(c_trav))
    return BVH(round_down_f32(nmin), round_up_f32(nmax),
               np.ascontiguousarray(na), np.ascontiguousarray(nc), idx, int(depth))


@njit(cache=True)
def _pack4(node_min, node_max, node_a, node_count, leaf_max, budget, pf, pi):
    n = node_a.shape[0]
    first = np.zeros(n, np.int64)
    cnt = np.zeros(n, np.int64)
    height = np.zeros(n, np.int64)
    area = np.zeros(n)
    # bottom-up: children have larger indices than their parent
    for i in range(n - 1, -1, -1):
        ex = np.float64(node_max[i, 0]) - node_min[i, 0]
        ey = np.float64(node_max[i, 1]) - node_min[i, 1]
        ez = np.float64(node_max[i, 2]) - node_min[i, 2]
        area[i] = ex * ey + ey * ez + ez * ex
        if node_count[i] > 0 or n == 1:
            first[i] = node_a[i]
            cnt[i] = node_count[i]
        else:
            r = node_a[i]
            first[i] = first[i + 1]
            cnt[i] = cnt[i + 1] + cnt[r]
            if cnt[i] > leaf_max:
                height[i] = 1 + max(height[i + 1], height[r])
    for k in range(4):   # record 0 starts empty: an empty tree stays that way
        pf[k] = np.inf
        pf[4 + k] = -np.inf
        pf[8 + k] = np.inf
        pf[12 + k] = -np.inf
        pf[16 + k] = np.inf
        pf[20 + k] = -np.inf
        pi[24 + k] = 0
        pi[28 + k] = -1
    if n == 1:
        if node_count[0] > 0:   # a lone leaf becomes the only child of the root record
            for k in range(3):
                pf[8 * k] = node_min[0, k]
                pf[8 * k + 4] = node_max[0, k]
            pi[24] = node_a[0]
            pi[28] = node_count[0]
        return 1, 0
    if height[0] == 0:          # small enough to be one leaf
        for k in range(3):
            pf[8 * k] = node_min[0, k]
            pf[8 * k + 4] = node_max[0, k]
        pi[24] = first[0]
        pi[28] = cnt[0]
        return 1, 0

    st_node = np.empty(n + 1, np.int64)
    st_slot = np.empty(n + 1, np.int64)
    st_acc = np.empty(n + 1, np.int64)
    st_node[0] = 0
    st_slot[0] = 0
    st_acc[0] = 0
    sp = 1
    nrec = 1
    need = 0
    ch = np.empty(4, np.int64)
    while sp > 0:
        sp -= 1
        i = st_node[sp]
        slot = st_slot[sp]
        acc = st_acc[sp]
        ch[0] = i + 1
        ch[1] = node_a[i]
        m = 2
        # open the largest interior child while the stack budget allows:
        # pushes along a path (m-1 per record) plus what binary records
        # would still need below must stay within `budget`
        while m < 4:
            best = -1
            best_area = -1.0
            for k in range(m):
                c = ch[k]
                if height[c] > 0 and area[c] > best_area:
                    best_area = area[c]
                    best = k
            if best < 0:
                break
            c = ch[best]
            hmax = max(height[c + 1], height[node_a[c]])
            for k in range(m):
                if k != best:
                    hmax = max(hmax, height[ch[k]])
            if acc + m + hmax > budget:
                break
            ch[best] = c + 1
            ch[m] = node_a[c]
            m += 1
        b = slot * 32
        for k in range(4):
            if k < m:
                c = ch[k]
                pf[b + k] = node_min[c, 0]
                pf[b + 4 + k] = node_max[c, 0]
                pf[b + 8 + k] = node_min[c, 1]
                pf[b + 12 + k] = node_max[c, 1]
                pf[b + 16 + k] = node_min[c, 2]
                pf[b + 20 + k] = node_max[c, 2]
                if height[c] == 0:
                    pi[b + 24 + k] = first[c]
                    pi[b + 28 + k] = cnt[c]
                else:
                    pi[b + 24 + k] = nrec
                    pi[b + 28 + k] = 0
                    st_node[sp] = c
                    st_slot[sp] = nrec
                    st_acc[sp] = acc + m - 1
                    sp += 1
                    nrec += 1
            else:
                pf[b + k] = np.inf
                pf[b + 4 + k] = -np.inf
                pf[b + 8 + k] = np.inf
                pf[b + 12 + k] = -np.inf
                pf[b + 16 + k] = np.inf
                pf[b + 20 + k] = -np.inf
                pi[b + 24 + k] = 0
                pi[b + 28 + k] = -1
        need = max(need, acc + m - 1)
    return nrec, need


def aligned_empty(n, dtype, align=64):
    """1-D array whose data starts on an `align`-byte boundary (cache-line records)."""
    dtype = np.dtype(dtype)
    buf = np.empty(n * dtype.itemsize + align, np.uint8)
    off = (-buf.ctypes.data) % align
    return buf[off:off + n * dtype.itemsize].view(dtype)


def pack_bvh(node_min, node_max, node_a, node_count, leaf_max=PACK_LEAF, budget=STACK_BUDGET):
    """Traversal layout: 4-wide records collapsed from the binary tree.

    Returns (pf float32[R*32], pi int32 view of pf, R, need). Record 0 is the
    root (an empty tree gives one record of empty slots). Words of a record:
    0-3 xlo, 4-7 xhi, 8-11 ylo, 12-15 yhi, 16-19 zlo, 20-23 zhi of children
    0..3, 24-27 child refs, 28-31 child counts: count > 0 is a leaf with
    items[ref:ref+count], count 0 an interior child whose record is ref,
    count -1 an unused slot (always after the used ones; its box is empty,
    +inf..-inf, so no ray could enter it anyway).
    Subtrees of at most `leaf_max` items become one leaf (their items are
    contiguous in depth-first order). `need` is the most stack entries a
    traversal can hold, never more than `budget`.
    """
    n = node_a.shape[0]
    pf = aligned_empty(max(n, 1) * REC_WORDS, np.float32)
    pi = pf.view(np.int32)
    nrec, need = _pack4(node_min, node_max, node_a, node_count, int(leaf_max), int(budget), pf, pi)
    pf = pf[:nrec * REC_WORDS]
    return pf, pf.view(np.int32), int(nrec), int(need)
