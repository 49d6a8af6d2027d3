"""The L-system graphs of a scene packed into one blob of the trace buffer
(engine/geometry/dcsg.py builds the graphs): layout constants, the ray scratch the
kernels need, OL stub records and `pack_blob`."""
from collections import namedtuple

import numpy as np

from ..lsystem.grammar import child_hash
from ..core.scene import SceneError
from .dcsg import ORGAN, chosen_children


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
ENTRY_F64, ENTRY_U64, ENTRY_I32 = 7, 2, 3
CACHE_STACK = 64                 # a cached subgraph's BVH is at most bvh.MAX_DEPTH deep
SCRATCH_WORDS = STACK_ENTRIES * (2 * ENTRY_F64 + 2 * ENTRY_U64 + ENTRY_I32) + 2 * MAX_DEPTH + 3 * CACHE_STACK + 16
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
        for c, to_parent, j in chosen_children(n, h):
            if has_stub(c):
                walk(c, child_hash(h, j), rot @ to_parent[:3, :3], parent)

    if has_stub(graph.root):
        walk(graph.root, graph.root_hash, np.eye(3), 0)
    out.sort(key=lambda r: r.address)
    return out


def stub_addresses(graph):
    """The graph's OL stub addresses, sorted: a hit's stub index points in here."""
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
