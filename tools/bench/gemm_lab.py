#!/usr/bin/env python3
"""Writes the GEMM lab's kernels and manifest for `raypatch-bench --gemm-lab DIR` (docs/PERFORMANCE.md, "The GEMM
lab"): the engine's own (`linear_tiled` and `linear` as shaders/ has them now) beside outer-product kernels of
several tilings, so that a tiling is timed against the engine's and cuBLAS on a lent GPU before it goes into
shaders/ (tools/codegen/gen_tiles.py writes the engine's). Add a variant by writing a function like `outer`.

    python3 tools/bench/gemm_lab.py [DIR]      # default target/gemm-lab
    raypatch-bench --gemm-lab target/gemm-lab --out OUT [--lab-only engine,op128]
"""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

PARAMS = """
struct Params {
    m: u32, n: u32, k4: u32, n4: u32, act: u32, slope: f32, has_bias: u32, accumulate: u32, w_ld4: u32,
    splits: u32, k_split4: u32, m_tiles: u32, norm: u32,
}
@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> w: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> bias: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> out: array<vec4<f32>>;
"""


def outer(out, bm, bn, tm, tn, bk, arrays=False, unroll_k=False):
    """An outer-product kernel: bm x bn tiles, tm x tn outputs an invocation, bk floats of K a step; its sums in
    named variables or an array (`arrays`), its K steps in a loop or written out (`unroll_k`)."""
    threads = (bm // tm) * (bn // tn)
    assert threads == 256, (bm, bn, tm, tn)
    rg, cg = tm // 4, tn // 4
    ty_n, tx_n = bm // tm, bn // tn
    bk4 = bk // 4
    lx = bm * bk4 // 256  # x vec4s per thread per step
    lw = bn * bk4 // 256
    assert lx >= 1 and lw >= 1
    s = [PARAMS]
    s.append(f"var<workgroup> xs: array<vec4<f32>, {bk * bm // 4}>;")
    s.append(f"var<workgroup> ws: array<vec4<f32>, {bk * bn // 4}>;")
    s.append("@compute @workgroup_size(256)")
    s.append("fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,"
             " @builtin(local_invocation_index) li: u32) {")
    s.append(f"    let tiles = (p.n + {bn - 1}u) / {bn}u;")
    s.append("    let group = wid.x + wid.y * nwg.x;")
    s.append(f"    let col0 = (group % tiles) * {bn}u;")
    s.append("    let rest = group / tiles;")
    s.append(f"    let row0 = (rest % p.m_tiles) * {bm}u;")
    s.append("    let split = rest / p.m_tiles;")
    s.append("    if (split >= p.splits) { return; }")
    s.append("    let k_begin = split * p.k_split4;")
    s.append("    let k_end = min(p.k4, k_begin + p.k_split4);")
    s.append(f"    let tx = li % {tx_n}u;")
    s.append(f"    let ty = li / {tx_n}u;")
    # staging addresses
    for l in range(lx):
        s.append(f"    let xe{l} = li + {256 * l}u;")
        s.append(f"    let xr{l} = xe{l} / {bk4}u; let xk{l} = xe{l} % {bk4}u;")
        s.append(f"    let xa{l} = min(row0 + xr{l}, p.m - 1u) * p.k4 + xk{l} + k_begin;")
    for l in range(lw):
        s.append(f"    let we{l} = li + {256 * l}u;")
        s.append(f"    let wr{l} = we{l} / {bk4}u; let wk{l} = we{l} % {bk4}u;")
        s.append(f"    let wa{l} = min(col0 + wr{l}, p.n - 1u) * p.w_ld4 + wk{l} + k_begin;")
    for l in range(lx):
        s.append(f"    var nx{l} = select(vec4<f32>(0.0), x[xa{l}], k_begin + xk{l} < k_end);")
    for l in range(lw):
        s.append(f"    var nw{l} = select(vec4<f32>(0.0), w[wa{l}], k_begin + wk{l} < k_end);")
    if arrays:
        s.append(f"    var acc = array<vec4<f32>, {rg * 4 * cg}>();")
    else:
        for g in range(rg):
            for r in range(4):
                for h in range(cg):
                    s.append(f"    var acc{g}_{r}_{h} = vec4<f32>(0.0);")
    s.append(f"    for (var k0 = k_begin; k0 < k_end; k0 += {bk4}u) {{")
    for l in range(lx):
        for c, comp in enumerate("xyzw"):
            s.append(f"        xs[(4u * xk{l} + {c}u) * {bm // 4}u + xr{l} / 4u][xr{l} % 4u] = nx{l}.{comp};")
    for l in range(lw):
        for c, comp in enumerate("xyzw"):
            s.append(f"        ws[(4u * wk{l} + {c}u) * {bn // 4}u + wr{l} / 4u][wr{l} % 4u] = nw{l}.{comp};")
    s.append("        workgroupBarrier();")
    for l in range(lx):
        s.append(f"        nx{l} = select(vec4<f32>(0.0), x[min(xa{l} + k0 - k_begin + {bk4}u, arrayLength(&x) - 1u)], "
                 f"k0 + {bk4}u + xk{l} < k_end);")
    for l in range(lw):
        s.append(f"        nw{l} = select(vec4<f32>(0.0), w[min(wa{l} + k0 - k_begin + {bk4}u, arrayLength(&w) - 1u)], "
                 f"k0 + {bk4}u + wk{l} < k_end);")
    ks = range(bk) if unroll_k else [None]
    if not unroll_k:
        s.append(f"        for (var kk = 0u; kk < {bk}u; kk++) {{")
    for kval in ks:
        kk = f"{kval}u" if kval is not None else "kk"
        ind = "            " if not unroll_k else "        "
        for g in range(rg):
            s.append(f"{ind}let a{g} = xs[{kk} * {bm // 4}u + {g * ty_n}u + ty];")
        for h in range(cg):
            s.append(f"{ind}let b{h} = ws[{kk} * {bn // 4}u + {h * tx_n}u + tx];")
        for g in range(rg):
            for r, comp in enumerate("xyzw"):
                for h in range(cg):
                    if arrays:
                        i = (g * 4 + r) * cg + h
                        s.append(f"{ind}acc[{i}] = fma(vec4<f32>(a{g}.{comp}), b{h}, acc[{i}]);")
                    else:
                        s.append(f"{ind}acc{g}_{r}_{h} = fma(vec4<f32>(a{g}.{comp}), b{h}, acc{g}_{r}_{h});")
        if unroll_k:
            s.append(f"{ind}{{}}")
    if not unroll_k:
        s.append("        }")
    s.append("        workgroupBarrier();")
    s.append("    }")
    for g in range(rg):
        for r in range(4):
            s.append(f"    let row{g}_{r} = row0 + 4u * ({g * ty_n}u + ty) + {r}u;")
            for h in range(cg):
                a = f"acc[{(g * 4 + r) * cg + h}]" if arrays else f"acc{g}_{r}_{h}"
                s.append(f"    {{ let c4 = col0 / 4u + {h * tx_n}u + tx;")
                s.append(f"      if (row{g}_{r} < p.m && c4 < p.n4) {{ out[(split * p.m + row{g}_{r}) * p.n4 + c4] = {a} + select(vec4<f32>(0.0), bias[c4], split == 0u); }} }}")
    s.append("}")
    # Unrolled-k variant has blocks re-declaring lets: wrap each k in braces.
    text = "\n".join(s)
    if unroll_k:
        # Put each k's body in its own scope.
        lines = text.split("\n")
        res = []
        for line in lines:
            if line.startswith("        let a0 = xs["):
                res.append("        {")
            if line == "        {}":
                res.append("        }")
                continue
            res.append(line)
        text = "\n".join(res)
    name = f"op{bm}x{bn}_{tm}x{tn}_bk{bk}" + ("_arr" if arrays else "") + ("_uk" if unroll_k else "")
    (out / f"{name}.wgsl").write_text(text + "\n")
    return [f"{name} {name}.wgsl main {bm} {bn} 5 auto"]



def main():
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "target" / "gemm-lab"
    out.mkdir(parents=True, exist_ok=True)
    engine = "\n".join((ROOT / "shaders" / f"{name}.wgsl").read_text() for name in ["activation", "tiles", "matmul"])
    (out / "engine.wgsl").write_text(engine)
    manifest = [
        "engine_tiled engine.wgsl linear_tiled 128 128 8 auto shaped",
        "engine_tiled_unshaped engine.wgsl linear_tiled 128 128 8 auto",
        # With a transformer's pre-norm in the prologue, as the engine's to_qkv, to_q and MLP-up layers run.
        "engine_tiled_norm engine.wgsl linear_tiled 128 128 8 auto shaped norm",
        "engine_rows engine.wgsl linear 256 8 5 1",
    ]
    manifest += outer(out, 128, 128, 8, 8, 8, unroll_k=True)
    manifest += outer(out, 128, 128, 8, 8, 8)
    manifest += outer(out, 128, 128, 8, 8, 8, arrays=True)
    manifest += outer(out, 64, 64, 4, 4, 16)
    (out / "manifest.txt").write_text("\n".join(manifest) + "\n")
    print(f"gemm_lab: {len(manifest)} kernels in {out}")


if __name__ == "__main__":
    main()
