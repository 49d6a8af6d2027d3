"""Photon-map baseline (Jensen 1996), the alternative of thesis 3.5.1.

The photon pass is this engine's own (trace_photons with keep_points), so both
methods see exactly the same photons; only storage and reconstruction differ:

* storage: every recorded hit kept as a point (position, normal, power),
  indexed by a kd-tree (scipy.spatial.cKDTree);
* reconstruction: irradiance at a point x with normal n from its k nearest
  photons, the disc estimate E = sum(power) / (pi r^2), r the distance to the
  k-th neighbour, counting only photons whose surface normal faces the same way
  as n (so light on the other side of a thin wall, or on a perpendicular wall at
  a corner, does not leak in).

It is evaluated at the world positions of lightmap texel centres, so its error
is scored on exactly the texels the lightmaps are scored on.
"""
import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

# Jensen's compact photon: position 12 B, RGBE power 4 B, direction 2 B, flags 2 B.
JENSEN_PHOTON_BYTES = 20
# Size of scipy's ckdtreenode (level, split_dim, split, children, start/end index,
# two child pointers; 8 bytes each on 64-bit builds), for the tree's node storage.
CKDTREE_NODE_BYTES = 72
# Normals closer than this cosine count as "facing the same way".
NORMAL_COS = 0.9


@dataclass
class PhotonMap:
    positions: np.ndarray     # (K, 3) float32
    normals: np.ndarray       # (K, 3) float32
    power: np.ndarray         # (K, B) float32
    tree: cKDTree
    seconds_build: float

    @property
    def n_photons(self):
        return int(self.positions.shape[0])

    def bytes_compact(self):
        """Memory at Jensen's 20 bytes per stored photon (tree implicit in a heap order)."""
        return self.n_photons * JENSEN_PHOTON_BYTES

    def bytes_measured(self):
        """What this implementation actually holds: its arrays, the tree's copy of the
        positions, its index permutation and its nodes."""
        arrays = self.positions.nbytes + self.normals.nbytes + self.power.nbytes
        tree = self.tree.data.nbytes + self.tree.indices.nbytes + int(self.tree.size) * CKDTREE_NODE_BYTES
        return int(arrays + tree)


def build(stats):
    """PhotonMap from a trace_photons(..., keep_points=True) result."""
    t0 = time.perf_counter()
    pts = np.asarray(stats.points)
    pos = np.ascontiguousarray(pts[:, :3], dtype=np.float32)
    nrm = np.ascontiguousarray(pts[:, 3:6], dtype=np.float32)
    power = np.ascontiguousarray(stats.point_power, dtype=np.float32)
    tree = cKDTree(pos, leafsize=16, balanced_tree=False, compact_nodes=False)
    return PhotonMap(pos, nrm, power, tree, time.perf_counter() - t0)


def irradiance(pm, points, normals, k=100, chunk=65536):
    """Disc estimate of irradiance E (N, B) at `points` (N, 3) with unit `normals` (N, 3)."""
    n = points.shape[0]
    nb = pm.power.shape[1]
    out = np.zeros((n, nb))
    if pm.n_photons == 0 or n == 0:
        return out
    k = int(min(k, pm.n_photons))
    for a in range(0, n, chunk):
        p, nn = points[a:a + chunk], normals[a:a + chunk]
        d, idx = pm.tree.query(p, k=k, workers=-1)
        if k == 1:
            d, idx = d[:, None], idx[:, None]
        r = d[:, -1]
        facing = np.einsum("ikj,ij->ik", pm.normals[idx], nn) > NORMAL_COS
        flux = np.einsum("ik,ikb->ib", facing.astype(np.float64), pm.power[idx].astype(np.float64))
        out[a:a + chunk] = flux / np.maximum(np.pi * r * r, 1e-300)[:, None]
    return out
