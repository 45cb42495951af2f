"""Semi-dense per-pixel inverse-depth filter (numba kernels + DepthMap + Mapper)."""
