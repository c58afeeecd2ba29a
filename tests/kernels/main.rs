//! Every kernel against its float64 CPU reference on random inputs and random shapes, including shapes
//! that are not multiples of the tile sizes (in the spirit of llama.cpp's test-backend-ops).

#[path = "../common/mod.rs"]
mod common;

mod attention;
mod concat;
mod conv;
mod conv_speed;
mod copy;
mod elementwise;
mod gru;
mod matmul;
mod mix;
mod multiply_adds;
mod norm;
mod pool;
mod posenc;
mod rays;
mod resize;
mod shaders;
mod softmax;
