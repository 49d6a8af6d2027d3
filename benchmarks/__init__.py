"""Speed-against-accuracy benchmarks: photon lightmaps, a photon map and Cycles."""
