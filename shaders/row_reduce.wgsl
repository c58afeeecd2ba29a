// The reduction of the kernels that take a workgroup per row (layernorm.wgsl's `layernorm_wide` and `row_stats`,
// softmax.wgsl's `softmax_rows_wide`; device::reduce_rows_per_workgroup), prepended to their shaders: WIDE
// invocations each reduce their share of the row (columns lid, lid + WIDE, ...), then combine their parts here.

const WIDE: u32 = 64u;
var<workgroup> partial: array<f32, WIDE>;

// What `workgroup_reduce` combines the parts with.
const REDUCE_SUM: u32 = 0u;
const REDUCE_MAX: u32 = 1u;

// The workgroup's `part`s combined by `op` in tree order (64 -> 1 in 6 halvings); every invocation gets the
// result. Call it in uniform control flow (it has barriers).
fn workgroup_reduce(lid: u32, part: f32, op: u32) -> f32 {
    partial[lid] = part;
    for (var half = WIDE / 2u; half > 0u; half /= 2u) {
        workgroupBarrier();
        if (lid < half) {
            let other = partial[lid + half];
            partial[lid] = select(partial[lid] + other, max(partial[lid], other), op == REDUCE_MAX);
        }
    }
    workgroupBarrier();
    let result = partial[0];
    // Before the next reduction overwrites it.
    workgroupBarrier();
    return result;
}
