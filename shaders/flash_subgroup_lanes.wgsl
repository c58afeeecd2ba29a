// Prepended to attention_flash.wgsl for its subgroup variants (adapters with subgroup operations): a query row's
// head is split over four neighbouring invocations of a subgroup, each holding every fourth vec4 of the query
// and of the accumulator, so that an invocation keeps a quarter of the registers and a workgroup has four times
// the invocations. Neighbouring local invocation indices are neighbouring lanes of one subgroup (subgroups are
// 4 lanes or more: device::KernelChoice::subgroup_lanes); the kernel tests check the sums on each adapter.

// Invocations per query row.
const LANES: u32 = 4u;

// The row's dot products with four keys, from this invocation's share of them: the four lanes' shares added by
// two butterfly shuffles. Float addition commutes, so all four lanes get the same sums bit for bit and their
// online softmax (max, rescale, weights) stays in step with no further exchange.
fn lanes_sum(partial: vec4<f32>) -> vec4<f32> {
    let pairs = partial + subgroupShuffleXor(partial, 1u);
    return pairs + subgroupShuffleXor(pairs, 2u);
}
