"""BVH builder and packer: structural invariants on random and degenerate inputs."""
import numpy as np
import pytest

from photon_lightmaps.engine.geometry.bvh import (MAX_DEPTH, MAX_LEAF, STACK_BUDGET, build_bvh, pack_bvh,
                        round_down_f32, round_up_f32)


def _boxes(kind, n, seed=0):
    rng = np.random.default_rng(seed)
    if kind == "random":
        c = rng.uniform(-10, 10, (n, 3))
        e = rng.uniform(0, 0.5, (n, 3))
        return c - e, c + e
    if kind == "same":                                    # all centroids equal
        lo = np.tile([1.0, 2.0, 3.0], (n, 1))
        return lo, lo + 1.0
    if kind == "flat":                                    # all in one plane, one line of centroids
        c = np.zeros((n, 3))
        c[:, 0] = rng.uniform(0, 1, n)
        return c, c
    if kind == "clustered":                               # far outlier + tight cluster
        c = rng.normal(0, 1e-6, (n, 3))
        c[0] = 1e6
        return c - 1e-7, c + 1e-7
    if kind == "geometric":                               # pathological for SAH depth
        x = 2.0 ** -np.arange(n, dtype=np.float64)
        c = np.stack([x, x, x], axis=1)
        return c, c + 1e-300
    raise ValueError(kind)


def _check_tree(bvh, lo, hi):
    n = lo.shape[0]
    nmin = bvh.node_min.astype(np.float64)
    nmax = bvh.node_max.astype(np.float64)
    a, cnt = bvh.node_a, bvh.node_count
    N = bvh.n_nodes
    assert bvh.node_min.dtype == np.float32 and bvh.node_a.dtype == np.int32
    assert bvh.items.dtype == np.int32
    if n == 0:
        assert N == 1 and np.all(nmin > nmax)             # empty box: nothing enters
        return
    # every item exactly once
    assert np.array_equal(np.sort(bvh.items), np.arange(n))
    seen = np.zeros(n, int)
    depth = np.zeros(N, int)
    parent_of = np.full(N, -1)
    for i in range(N):
        if cnt[i] > 0:
            assert cnt[i] <= MAX_LEAF
            it = bvh.items[a[i]:a[i] + cnt[i]]
            seen[it] += 1
            # leaf box contains its items (conservative float32)
            assert np.all(nmin[i] <= lo[it]) and np.all(nmax[i] >= hi[it])
        else:
            left, right = i + 1, a[i]
            assert i < right < N and left < N              # depth-first, left adjacent
            for ch in (left, right):
                assert parent_of[ch] == -1
                parent_of[ch] = i
                depth[ch] = depth[i] + 1
                assert np.all(nmin[i] <= nmin[ch]) and np.all(nmax[i] >= nmax[ch])
    assert np.all(seen == 1)
    assert np.all(parent_of[1:] >= 0)                      # a single tree
    assert depth.max() <= MAX_DEPTH and bvh.depth == depth.max()


@pytest.mark.parametrize("kind,n", [("random", 0), ("random", 1), ("random", 2), ("random", 5),
                                    ("random", 3000), ("same", 1), ("same", 257),
                                    ("flat", 500), ("clustered", 400), ("geometric", 300)])
def test_tree_invariants(kind, n):
    lo, hi = _boxes(kind, n)
    bvh = build_bvh(lo, hi)
    _check_tree(bvh, lo, hi)


def test_sah_beats_median_on_clustered_input():
    # two tight clusters far apart: the root split must separate them
    rng = np.random.default_rng(3)
    c = np.concatenate([rng.normal(0, 0.01, (200, 3)), rng.normal(100, 0.01, (50, 3))])
    bvh = build_bvh(c, c)
    left = bvh.node_max[1].astype(np.float64)
    right_lo = bvh.node_min[bvh.node_a[0]].astype(np.float64)
    assert (left.max() < 50) != (right_lo.min() < 50)


def test_outward_rounding():
    x = np.array([0.1, -0.1, 1e-30, -1e-30, 3.0, 1e39, -1e39, 0.0])
    d = round_down_f32(x).astype(np.float64)
    u = round_up_f32(x).astype(np.float64)
    assert np.all(d <= x) and np.all(u >= x)
    assert np.all(d[[4, 7]] == x[[4, 7]])                 # exact values stay exact


def _walk_packed(pi, n_items):
    """Items reached through the packed records, and the worst stack use."""
    rec = pi.reshape(-1, 32)
    seen = np.zeros(n_items, int)
    worst = 0
    todo = [(0, 0)]                       # (record, entries its ancestors may have pushed)
    visited = set()
    while todo:
        r, acc = todo.pop()
        assert r not in visited
        visited.add(r)
        inner = []
        for k in range(4):
            a, c = rec[r, 24 + k], rec[r, 28 + k]
            if c > 0:
                seen[a:a + c] += 1
            elif c == 0:
                inner.append(a)
        pushes = max(len(inner) - 1, 0)   # all hit interior children but the nearest
        worst = max(worst, acc + pushes)
        todo.extend((a, acc + pushes) for a in inner)
        # unused slots come last
        used = rec[r, 28:32] >= 0
        assert not np.any(np.diff(used.astype(int)) > 0)
    assert len(visited) == rec.shape[0]                   # no orphan records
    return seen, worst


@pytest.mark.parametrize("kind,n", [("random", 0), ("random", 1), ("random", 3), ("random", 5000),
                                    ("same", 100), ("geometric", 300)])
def test_packed_records(kind, n):
    lo, hi = _boxes(kind, n, seed=1)
    bvh = build_bvh(lo, hi)
    pf, pi, m, need = pack_bvh(bvh.node_min, bvh.node_max, bvh.node_a, bvh.node_count)
    assert pf.ctypes.data % 64 == 0 and m == pf.size // 32
    seen, worst = _walk_packed(pi, n)
    assert np.all(seen == 1)                              # items are positions into bvh.items
    assert worst <= need <= STACK_BUDGET
    rec = pf.reshape(-1, 32)
    ri = pi.reshape(-1, 32)
    for r in range(m):
        for k in range(4):
            c, a = ri[r, 28 + k], ri[r, 24 + k]
            if c < 0:
                assert rec[r, k] == np.inf and rec[r, 4 + k] == -np.inf
            elif c > 0:                                  # leaf box contains its items
                it = bvh.items[a:a + c]
                for ax in range(3):
                    assert rec[r, 8 * ax + k] <= lo[it, ax].min()
                    assert rec[r, 8 * ax + 4 + k] >= hi[it, ax].max()


def test_million_items_build():
    lo, hi = _boxes("random", 1_000_000, seed=2)
    bvh = build_bvh(lo, hi)
    assert np.array_equal(np.sort(bvh.items), np.arange(lo.shape[0]))
    assert bvh.depth <= MAX_DEPTH
    leaf = bvh.node_count > 0
    assert bvh.node_count[leaf].sum() == lo.shape[0]
