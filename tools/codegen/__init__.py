"""Generators of WGSL shaders (shaders/matmul_lanes.wgsl)."""
