enable f16;
enable wgpu_cooperative_matrix;

// The tensor kernels' cooperative-matrix size, CT x CT x CT, f16 operands and f32 accumulators: the first prelude of
// coop_tiles.wgsl's and attention_coop.wgsl's shaders (its `enable` directives must come first). 16 here, for
// NVIDIA and AMD; the 8x8 variants (Apple, Mesa's lavapipe) replace these four lines (kernels/mod.rs, COOP_8).
const CT: u32 = 16u;
alias CoopA = coop_mat16x16<f16, A>;
alias CoopB = coop_mat16x16<f16, B>;
alias CoopC = coop_mat16x16<f32, C>;
