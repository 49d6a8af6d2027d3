"""The trace buffer: one 64-byte aligned byte array holding everything the ray
traversal reads (engine/geometry/raycast.py), so a kernel takes one array
instead of ~40. A header of int64 words, then the 4-wide records of both BVH
levels (engine/geometry/bvh.py `pack_bvh`), triangles as 4-lane packets, and
the per-shape, primitive and instance arrays the traversal needs; CSG solids
and L-system graphs add blobs of their own (header words H_CSG, H_DCSG).
engine/geometry/assembly.py fills it."""
import mmap

import numpy as np
from numba import njit

from .bvh import REC_WORDS, STACK_BUDGET, aligned_empty, pack_bvh
from .dcsg_blob import DCSG_REF, H_DCSG, SCRATCH_WORDS
from .csg import CSG, CSG_SCRATCH_WORDS, H_CSG

# Count flag of a packed BLAS leaf made only of triangles: its ref is then the
# first of `count - TRI_LEAF` consecutive packets, each holding up to four
# triangles side by side, which the traversal tests as one vector. Other
# leaves keep (first shape, count) and go through the per-shape references.
TRI_LEAF = 1 << 24

# Layout of the trace buffer: a header of int64 words, then four sections,
# each 64-byte aligned: records (float32/int32, TLAS first), int32 data,
# float64 data. The header holds byte offsets of the sections and element
# offsets of the arrays inside them.
TRACE_HEADER = 32
H_REC, H_REC_END, H_I32, H_I32_END, H_F64, H_F64_END = 0, 1, 2, 3, 4, 5
H_BLAS_REC = 6        # record index of the first BLAS record
H_SHAPE_REF = 7       # int32[S]: packet code 4*pk+lane of a triangle, or -1 - primitive row
H_LANE_SHAPE = 8      # int32[4P]: shape id of each packet lane (-1 unused)
H_PROTO_SLOT = 9      # int32[NP]: root record of each prototype (absolute)
H_INST_PROTO = 10     # int32[I]
H_TLAS_ITEMS = 11     # int32[..]: instance ids in TLAS leaf order
H_PRIM_KIND = 12      # int32[P]
H_TRI4 = 13           # float64[P*36]: packet pk, vertex v, axis k, lane q at 36pk+12v+4k+q
H_INST_INV = 14       # float64[I*12]: 3x4 row-major
H_PRIM_INV = 15       # float64[P*12]
H_PRIM_PARAMS = 16    # float64[P*4]
H_INST_IDENT = 17     # int32[I]: 1 if the instance transform is the identity
H_SINGLE = 18         # the only instance in the TLAS, or -1 (then the TLAS is walked)
# word 19 is reserved for engine/geometry/csg.py (H_CSG: its blob's offset in the float64 section),
# word 20 for engine/geometry/dcsg_blob.py (H_DCSG: the L-system graphs' blob)

# Stack words a two-level traversal may need: two int32 words per entry,
# at most STACK_BUDGET entries per level (guaranteed by bvh.pack_bvh). The
# ray-CSG kernel's interval lists follow (engine/geometry/csg.py), so no ray allocates.
TRAV_WORDS = 2 * 2 * STACK_BUDGET
STACK_WORDS = TRAV_WORDS + CSG_SCRATCH_WORDS + SCRATCH_WORDS   # then the DCSG ray stack
# shape_ref of a CSG solid: CSG_REF - root node (far below any -1 - primitive row)
CSG_REF = -(1 << 30)
# shape kind of an L-system (after CSG); its shape_ref is dcsg_blob.DCSG_REF - graph
DCSG = CSG + 1


@njit(cache=True)
def _fill_packets(first, count, pk_first, shape_kind, shape_index, tri_p,
                  tri4, lane_shape, shape_ref):
    """Puts the triangles of each leaf (shapes first[i]..+count[i]) into its
    packets and records where every shape went."""
    for i in range(first.shape[0]):
        q = 0
        for s in range(first[i], first[i] + count[i]):
            if shape_kind[s] != 0:
                shape_ref[s] = -1 - shape_index[s]
                continue
            pk = pk_first[i] + q // 4
            lane = q % 4
            q += 1
            code = 4 * pk + lane
            shape_ref[s] = code
            lane_shape[code] = s
            j = shape_index[s]
            for v in range(3):
                for k in range(3):
                    tri4[36 * pk + 12 * v + 4 * k + lane] = tri_p[j, v, k]


def _huge_buffer(nbytes):
    """Zeroed byte array, 2 MiB aligned and advised to use transparent huge
    pages where the OS offers them (Linux 'madvise' mode): rays wander over
    megabytes of records and triangles, and with 4 KiB pages they also miss
    the TLB."""
    huge = 1 << 21
    if nbytes < huge:
        buf = aligned_empty(nbytes, np.uint8)
        buf[:] = 0
        return buf
    size = (nbytes + 2 * huge - 1) // huge * huge
    m = mmap.mmap(-1, size)                      # anonymous, zero-filled
    if hasattr(mmap, "MADV_HUGEPAGE"):
        try:
            m.madvise(mmap.MADV_HUGEPAGE)
        except OSError:
            pass
    raw = np.frombuffer(m, dtype=np.uint8)
    off = (-raw.ctypes.data) % huge
    return raw[off:off + nbytes]


def _build_trace(records, rec_tlas, i32_parts, f64_parts, extra=()):
    """Assembles the trace buffer from record words and named array parts."""
    def up64(n):
        return (n + 63) // 64 * 64
    hdr = np.zeros(TRACE_HEADER, np.int64)
    rec0 = up64(TRACE_HEADER * 8)
    i320 = up64(rec0 + records.nbytes)
    off, i32 = {}, []
    n = 0
    for key, a in i32_parts:
        off[key] = n
        i32.append(np.asarray(a, np.int32).reshape(-1))
        n += i32[-1].size
    i32 = np.concatenate(i32) if i32 else np.zeros(0, np.int32)
    f640 = up64(i320 + i32.nbytes)
    f64 = []
    n = 0
    for key, a in f64_parts:
        if key == H_DCSG and n % 8:     # 64-byte aligned: the blob's records need 16
            f64.append(np.zeros(8 - n % 8))
            n += f64[-1].size
        off[key] = n
        f64.append(np.asarray(a, np.float64).reshape(-1))
        n += f64[-1].size
    f64 = np.concatenate(f64) if f64 else np.zeros(0)
    total = up64(f640 + f64.nbytes)
    buf = _huge_buffer(total)
    hdr[[H_REC, H_REC_END, H_I32, H_I32_END, H_F64, H_F64_END]] = (
        rec0, rec0 + records.nbytes, i320, i320 + i32.nbytes, f640, f640 + f64.nbytes)
    hdr[H_BLAS_REC] = rec_tlas
    for key, value in extra:
        hdr[key] = value
    for key, o in off.items():
        hdr[key] = o
    buf[:TRACE_HEADER * 8] = hdr.view(np.uint8)
    buf[rec0:rec0 + records.nbytes] = records.view(np.uint8)
    buf[i320:i320 + i32.nbytes] = i32.view(np.uint8)
    buf[f640:f640 + f64.nbytes] = f64.view(np.uint8)
    return buf


def trace_arrays_raw(buf):
    """(tlas_pf, blas_pf, tlas_pi, blas_pi): record views into a trace buffer."""
    hdr = buf[:TRACE_HEADER * 8].view(np.int64)
    recf = buf[hdr[H_REC]:hdr[H_REC_END]].view(np.float32)
    reci = recf.view(np.int32)
    k = int(hdr[H_BLAS_REC]) * REC_WORDS
    return recf[:k], recf[k:], reci[:k], reci[k:]


def trace_arrays(g):
    """Named views of the trace buffer (for tests and debugging)."""
    buf = g.trace
    hdr = buf[:TRACE_HEADER * 8].view(np.int64)
    rec = buf[hdr[H_REC]:hdr[H_REC_END]].view(np.int32)
    i32 = buf[hdr[H_I32]:hdr[H_I32_END]].view(np.int32)
    f64 = buf[hdr[H_F64]:hdr[H_F64_END]].view(np.float64)
    n_pk = (hdr[H_INST_INV] - hdr[H_TRI4]) // 36
    return {
        "records": rec.reshape(-1, REC_WORDS), "blas_record0": int(hdr[H_BLAS_REC]),
        "shape_ref": i32[hdr[H_SHAPE_REF]:hdr[H_LANE_SHAPE]],
        "lane_shape": i32[hdr[H_LANE_SHAPE]:hdr[H_PROTO_SLOT]],
        "tri4": f64[hdr[H_TRI4]:hdr[H_INST_INV]].reshape(n_pk, 3, 3, 4),
    }


def pack_trace(sa, blas, inst, tlas, csg_blob, dcsg_blob):
    """The trace buffer: both BVHs' records, packets and the arrays the traversal reads."""
    # TLAS records first, then the BLAS records (their child refs shift by that)
    blas_rec = (np.concatenate(blas.rec_parts) if blas.rec_parts
                else np.zeros((0, REC_WORDS), np.int32))
    blas_rec = blas_rec.copy()
    inner = blas_rec[:, 28:32] == 0
    blas_rec[:, 24:28][inner] += tlas.n_rec
    records = np.concatenate([tlas.pi.reshape(-1, REC_WORDS), blas_rec]).reshape(-1)
    # identity instances let the traversal reuse the world ray's setup; a
    # single instance needs no TLAS walk at all (its root box test repeats
    # the BLAS one)
    ident = np.all(inst.xf == np.eye(4)[:3], axis=(1, 2)).astype(np.int32).reshape(-1)
    items = tlas.items
    return _build_trace(
        records, tlas.n_rec,
        [(H_SHAPE_REF, blas.shape_ref), (H_LANE_SHAPE, blas.lane_shape),
         (H_PROTO_SLOT, blas.proto_slot + tlas.n_rec), (H_INST_PROTO, inst.proto),
         (H_TLAS_ITEMS, items), (H_PRIM_KIND, sa.prim_kind), (H_INST_IDENT, ident)],
        [(H_TRI4, blas.tri4), (H_INST_INV, inst.inv), (H_PRIM_INV, sa.prim_inv),
         (H_PRIM_PARAMS, sa.prim_params), (H_CSG, csg_blob), (H_DCSG, dcsg_blob)],
        extra=[(H_SINGLE, int(items[0]) if len(items) == 1 else -1)])


def trace_buf(g):
    """What the traversal cores take of a Geometry: its four trace views and its features marker."""
    return (g.trace_i64, g.trace_f32, g.trace_i32, g.trace_f64, g.trace_features)


def new_stack():
    """Traversal stack for one thread: reuse it for every ray of that thread."""
    return np.empty(STACK_WORDS, np.int32)


def pack_blas(proto_root, n_nodes, blas_min, blas_max, blas_a, blas_count, shape_kind,
               shape_index, tri_p, n_shapes):
    """4-wide traversal records of every prototype's BLAS (absolute record ids),
    and the triangles of pure-triangle leaves as 4-lane packets."""
    non_tri_before = np.concatenate([[0], np.cumsum(shape_kind != 0)])
    leaf_first, leaf_count, leaf_pk = [], [], []
    n_packets = 0
    rec_parts = []
    proto_slot = np.zeros(len(proto_root), np.int32)
    n_rec = 0
    blas_need = 0
    for p in range(len(proto_root)):
        r0 = proto_root[p]
        r1 = proto_root[p + 1] if p + 1 < len(proto_root) else n_nodes
        cnt = blas_count[r0:r1]
        a_local = blas_a[r0:r1].copy()
        a_local[cnt == 0] -= r0               # interior children: local node index
        _, pi, m, need = pack_bvh(blas_min[r0:r1], blas_max[r0:r1], a_local, cnt)
        pi = pi.reshape(m, REC_WORDS).copy()
        refs = pi[:, 24:28]
        cnts = pi[:, 28:32]
        refs[cnts == 0] += n_rec              # child records become absolute
        leaf = cnts > 0
        first = refs[leaf].astype(np.int64)
        c = cnts[leaf].astype(np.int64)
        n_tri = c - (non_tri_before[first + c] - non_tri_before[first])
        n_pk = (n_tri + 3) // 4
        pk_first = n_packets + np.concatenate([[0], np.cumsum(n_pk)[:-1]]).astype(np.int64)
        n_packets += int(n_pk.sum())
        leaf_first.append(first)
        leaf_count.append(c)
        leaf_pk.append(pk_first)
        pure = n_tri == c
        refs[leaf] = np.where(pure, pk_first, first)
        cnts[leaf] = np.where(pure, n_pk + TRI_LEAF, c)
        rec_parts.append(pi)
        proto_slot[p] = n_rec
        n_rec += m
        blas_need = max(blas_need, need)
    tri4 = np.full(n_packets * 36, np.nan)    # unused lanes are NaN: they never hit
    lane_shape = np.full(n_packets * 4, -1, np.int32)
    shape_ref = np.zeros(n_shapes, np.int32)
    if leaf_first:
        _fill_packets(np.concatenate(leaf_first), np.concatenate(leaf_count),
                      np.concatenate(leaf_pk), shape_kind, shape_index, tri_p,
                      tri4, lane_shape, shape_ref)
    is_csg = shape_kind[:n_shapes] == CSG
    shape_ref[is_csg] = CSG_REF - shape_index[:n_shapes][is_csg]
    is_dcsg = shape_kind[:n_shapes] == DCSG
    shape_ref[is_dcsg] = DCSG_REF - shape_index[:n_shapes][is_dcsg]

    return rec_parts, proto_slot, blas_need, tri4, lane_shape, shape_ref, n_packets
