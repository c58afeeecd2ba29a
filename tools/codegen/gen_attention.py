#!/usr/bin/env python3
"""Writes every use of flash attention's registers into shaders/attention_flash.wgsl, between its BEGIN/END lines:
a lane's share of its query row's query and output accumulator, REGS vec4s each, as named variables (`q_0`,
`o_0`, ...) rather than arrays indexed in loops, which NVIDIA's Vulkan driver keeps in memory (the GEMM lab of
docs/PERFORMANCE.md; WGSL has no loop that unrolls at compile time). Register t of lane `lane` holds chunk
t * LANES + lane of the head. The kernel's variants (32, 16 or 8 chunks a head, over one or four lanes:
kernels::attention) share the source: the uses of registers past the fewest any variant has sit in
`if (REGS > n)` blocks, which compile away. MAX_DIM_HEAD in crates/raypatch-engine/src/kernels/attention.rs
and FLASH_LANES in crates/raypatch-engine/src/device.rs size it; `cargo test --test kernels shaders` fails when
the shader is not what this script writes (`--check`).

    python3 tools/codegen/gen_attention.py          # rewrite the shader
    python3 tools/codegen/gen_attention.py --check  # exit 1 if the shader is not what this script writes
"""
from common import ROOT, rust_const, write_or_check, written_out

SHADER = ROOT / "shaders" / "attention_flash.wgsl"
MAX_CHUNKS = rust_const("kernels/attention.rs", "MAX_DIM_HEAD") // 4
SUBGROUP_LANES = rust_const("device.rs", "FLASH_LANES")
# Chunks a head of each variant holds, and lanes a row is split over: one, or SUBGROUP_LANES.
CHUNKS = [8, 16, MAX_CHUNKS]
# The variants' register counts, fewest first: the uses of register t sit under the guard of the largest count
# below t.
REGS = sorted({chunks // lanes for chunks in CHUNKS for lanes in (1, SUBGROUP_LANES)})
KEYS = 4  # keys a row takes at a time (dots_0 .. dots_3 in the shader)


def by_register(line, guarded=True):
    """body(indent) of `line(t)` for every register, guarded by REGS past the fewest of any variant (`guarded`)."""
    def body(indent):
        out, lower = [], 0
        for count in REGS if guarded else [REGS[-1]]:
            inner = indent if lower == 0 else indent + "    "
            if lower:
                out.append(f"{indent}if (REGS > {lower}u) {{")
            out += [f"{inner}{text}" for t in range(lower, count) for text in line(t)]
            if lower:
                out.append(f"{indent}}}")
            lower = count
        return "".join(f"{text}\n" for text in out)
    return body


def chunk(t):
    """The head's chunk in register t of lane `lane`."""
    return f"{t}u * LANES + lane"


def registers(t):
    """Register t's variables, declared whatever REGS is (a guard's block would scope them); a variant's compiler
    drops those it never uses."""
    return [f"var q_{t} = query_chunk(i, q_at, {chunk(t)});", f"var o_{t} = vec4<f32>(0.0);"]


def scores(t):
    """Register t's products with the tile's keys j .. j + 3 (key g's chunk c at kb - lane + g * CHUNKS + c)."""
    return [f"dots_{g} = fma(q_{t}, k_tile[kb + {g}u * CHUNKS + {t}u * LANES], dots_{g});" for g in range(KEYS)]


def accumulate(t):
    """Register t of the output rescaled to the new max, plus the four keys' weighted values, in key order."""
    value = f"o_{t} * corr"
    for g, lane in enumerate("xyzw"):
        value = f"fma(vec4<f32>(weights.{lane}), v_tile[kb + {g}u * CHUNKS + {t}u * LANES], {value})"
    return [f"o_{t} = {value};"]


def store(t):
    return [f"store_chunk(at, {chunk(t)}, o_{t} * scale);"]


def main():
    text = SHADER.read_text()
    text = written_out(text, SHADER, "registers", by_register(registers, guarded=False))
    for name, line in [("scores", scores), ("accumulate", accumulate), ("store", store)]:
        text = written_out(text, SHADER, name, by_register(line))
    write_or_check({SHADER: text})


if __name__ == "__main__":
    main()
