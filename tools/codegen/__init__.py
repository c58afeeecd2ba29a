"""Generators of WGSL shaders: shaders/matmul_lanes.wgsl (gen_matmul_lanes.py), shaders/tiles.wgsl and the GPU
GEMMs' register blocks (gen_tiles.py), flash attention's registers (gen_attention.py); common.py is what they
share. Run them as scripts."""
