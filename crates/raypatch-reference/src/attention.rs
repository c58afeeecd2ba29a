//! Multi-head attention in float64: `softmax(q kᵀ · scale) v` per head, heads split as `(h d)`.

/// `q`: `[nq, q_ld]`, `k`: `[nkv, k_ld]`, `v`: `[nkv, v_ld]` row-major (unpadded: `*_ld` is the column
/// count). Head `h` uses columns `q_col + h*dim_head ..` of q, `k_col + h*dim_head ..` of k and
/// `v_col + h*dim_head ..` of v. Returns `[nq, heads*dim_head]` with
/// `out[i, h*dh + d] = Σ_j softmax_j(scale · q_i,h · k_j,h) · v[j, v_col + h*dh + d]`, the softmax taken
/// with its maximum subtracted.
#[allow(clippy::too_many_arguments)]
pub fn attention(
    q: &[f64],
    q_ld: usize,
    q_col: usize,
    k: &[f64],
    k_ld: usize,
    k_col: usize,
    v: &[f64],
    v_ld: usize,
    v_col: usize,
    nq: usize,
    nkv: usize,
    heads: usize,
    dim_head: usize,
    scale: f64,
) -> Vec<f64> {
    let inner = heads * dim_head;
    assert!(q.len() >= nq * q_ld && q_col + inner <= q_ld, "q too small");
    assert!(k.len() >= nkv * k_ld && k_col + inner <= k_ld, "k too small");
    assert!(v.len() >= nkv * v_ld && v_col + inner <= v_ld, "v too small");
    let mut out = vec![0.0; nq * inner];
    let mut logits = vec![0.0; nkv];
    for i in 0..nq {
        for h in 0..heads {
            let qi = &q[i * q_ld + q_col + h * dim_head..][..dim_head];
            for (j, logit) in logits.iter_mut().enumerate() {
                let kj = &k[j * k_ld + k_col + h * dim_head..][..dim_head];
                *logit = scale * qi.iter().zip(kj).map(|(a, b)| a * b).sum::<f64>();
            }
            let max = logits.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let weights: Vec<f64> = logits.iter().map(|s| (s - max).exp()).collect();
            let sum: f64 = weights.iter().sum();
            let oi = &mut out[i * inner + h * dim_head..][..dim_head];
            for (j, w) in weights.iter().enumerate() {
                let vj = &v[j * v_ld + v_col + h * dim_head..][..dim_head];
                for (o, x) in oi.iter_mut().zip(vj) {
                    *o += w / sum * x;
                }
            }
        }
    }
    out
}
