#!/usr/bin/env python3
"""Writes every use of flash attention's registers into shaders/attention_flash.wgsl, between its BEGIN/END lines:
the query and the output accumulator of an invocation's query row, CHUNKS vec4s each, as named variables (`q_0`,
`o_0`, ...) rather than arrays indexed in loops, which NVIDIA's Vulkan driver keeps in memory (the GEMM lab of
docs/PERFORMANCE.md; WGSL has no loop that unrolls at compile time). The kernel's variants (32, 16 and 8 chunks,
kernels::attention) share the source: the uses of chunks 8 and up sit in `if (CHUNKS > 8u)` blocks, and of 16
and up in `if (CHUNKS > 16u)`, which compile away. MAX_DIM_HEAD in crates/raypatch-engine/src/kernels/attention.rs
sizes it; `cargo test --test kernels shaders` fails when the shader is not what this script writes (`--check`).

    python3 tools/codegen/gen_attention.py          # rewrite the shader
    python3 tools/codegen/gen_attention.py --check  # exit 1 if the shader is not what this script writes
"""
from common import ROOT, rust_const, write_or_check, written_out

SHADER = ROOT / "shaders" / "attention_flash.wgsl"
MAX_CHUNKS = rust_const("kernels/attention.rs", "MAX_DIM_HEAD") // 4
# The variants' chunk counts, smallest first: the uses of chunk c sit under the guard of the largest count below c.
VARIANTS = [8, 16, MAX_CHUNKS]
KEYS = 4  # keys an invocation takes at a time (dots_0 .. dots_3 in the shader)


def by_chunk(line, guarded=True):
    """body(indent) of `line(c)` for every chunk, guarded by CHUNKS past the smallest variant's (`guarded`)."""
    def body(indent):
        out, lower = [], 0
        for count in VARIANTS if guarded else [MAX_CHUNKS]:
            inner = indent if lower == 0 else indent + "    "
            if lower:
                out.append(f"{indent}if (CHUNKS > {lower}u) {{")
            out += [f"{inner}{text}" for c in range(lower, count) for text in line(c)]
            if lower:
                out.append(f"{indent}}}")
            lower = count
        return "".join(f"{text}\n" for text in out)
    return body


def registers(c):
    """Chunk c's variables, declared whatever CHUNKS is (a guard's block would scope them); a variant's compiler
    drops those it never uses."""
    return [f"var q_{c} = query_chunk(i, q_at, {c}u);", f"var o_{c} = vec4<f32>(0.0);"]


def scores(c):
    """Chunk c's products with the tile's keys j .. j + 3 (key g's chunk c at kb + g * CHUNKS + c)."""
    return [f"dots_{g} = fma(q_{c}, k_tile[kb + {g}u * CHUNKS + {c}u], dots_{g});" for g in range(KEYS)]


def accumulate(c):
    """Chunk c of the output rescaled to the new max, plus the four keys' weighted values, in key order."""
    value = f"o_{c} * corr"
    for g, lane in enumerate("xyzw"):
        value = f"fma(vec4<f32>(weights.{lane}), v_tile[kb + {g}u * CHUNKS + {c}u], {value})"
    return [f"o_{c} = {value};"]


def store(c):
    return [f"store_chunk(at, {c}u, o_{c} * scale);"]


def main():
    text = SHADER.read_text()
    text = written_out(text, SHADER, "registers", by_chunk(registers, guarded=False))
    for name, line in [("scores", scores), ("accumulate", accumulate), ("store", store)]:
        text = written_out(text, SHADER, name, by_chunk(line))
    write_or_check({SHADER: text})


if __name__ == "__main__":
    main()
