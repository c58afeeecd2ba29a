//! The GRU cell's gates (`shaders/gru.wgsl`), after its two gate projections (ordinary linear layers):
//! PyTorch's `nn.GRUCell`, which slot attention uses to update the slots.

use super::GRU;
use crate::plan::{grid, Access, Op, PlanBuilder, View};

params! {
    /// The uniform of `shaders/gru.wgsl`.
    GruParams {
        rows: u32,
        dim: u32,
        /// Floats per row of gi and gh.
        gates_ld: u32,
        /// Floats per row of h and out.
        ld: u32,
    }
}

/// A GRU cell's operands: see [`gru_cell`].
#[derive(Clone, Copy, Debug)]
pub struct GruArgs {
    /// `[rows, 3·dim]`: `x · W_ihᵀ + b_ih`, gates in PyTorch's order r, z, n.
    pub gi: View,
    /// `[rows, 3·dim]`: `h · W_hhᵀ + b_hh`.
    pub gh: View,
    /// `[rows, dim]`: the previous state.
    pub h: View,
    /// `[rows, dim]` view of another tensor: the new state.
    pub out: View,
}

/// Invocations per workgroup: one per element of the output.
const GROUP_SIZE: usize = 64;

/// `r = σ(gi_r + gh_r)`, `z = σ(gi_z + gh_z)`, `n = tanh(gi_n + r·gh_n)`, `out = (h - n)·z + n`. Writes every
/// element of `out` (padding zero). Records no multiply-adds (elementwise; the projections are linears).
pub fn gru_cell(plan: &mut PlanBuilder, label: &str, args: GruArgs) {
    let GruArgs { gi, gh, h, out } = args;
    let dim = plan.cols(h.id);
    for (name, v) in [("gi", gi), ("gh", gh)] {
        assert!(
            v.rows == h.rows && plan.cols(v.id) == 3 * dim,
            "gru_cell {label}: {name} is {}x{}, expected {}x{}",
            v.rows,
            plan.cols(v.id),
            h.rows,
            3 * dim
        );
    }
    assert!(plan.ld(gi.id) == plan.ld(gh.id), "gru_cell {label}: gi and gh rows differ in stride");
    assert!(
        out.rows == h.rows && plan.cols(out.id) == dim && plan.ld(out.id) == plan.ld(h.id) && out.id != h.id,
        "gru_cell {label}: out must be another {}x{dim} tensor",
        h.rows
    );
    let ld = plan.ld(out.id);
    let params = GruParams { rows: h.rows as u32, dim: dim as u32, gates_ld: plan.ld(gi.id) as u32, ld: ld as u32 };
    plan.push(Op {
        label: label.to_string(),
        shader: &GRU,
        entry: "gru_cell",
        params: params.words(),
        bindings: vec![(gi, Access::Read), (gh, Access::Read), (h, Access::Read), (out, Access::Write)],
        textures: Vec::new(),
        workgroups: grid((h.rows * ld).div_ceil(GROUP_SIZE)),
        constants: Vec::new(),
        multiply_adds: 0,
    });
}
