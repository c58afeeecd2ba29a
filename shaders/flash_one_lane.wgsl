// Prepended to attention_flash.wgsl for its variants without subgroups: an invocation holds a query row's whole
// head, so its dot products are whole where they are summed.

// Invocations per query row.
const LANES: u32 = 1u;

// The row's dot products with four keys, from this invocation's share of them: all of them.
fn lanes_sum(partial: vec4<f32>) -> vec4<f32> {
    return partial;
}
