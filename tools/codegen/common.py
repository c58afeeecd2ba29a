"""What the shader generators share: the engine's constants they size the kernels by, the regions of a
hand-written shader they write between BEGIN/END lines, and `--check` (does the shader hold what the script
writes; `cargo test --test kernels shaders` runs it for every generator)."""
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ENGINE = ROOT / "crates" / "raypatch-engine" / "src"


def rust_const(file, name):
    """The value of `[pub(crate)] const NAME: type = <integer expression>;` in the engine's source file `file`."""
    match = re.search(rf"\bconst {name}: \w+ = ([0-9 *+]+);", (ENGINE / file).read_text())
    if not match:
        sys.exit(f"{Path(sys.argv[0]).name}: no `const {name}` with an integer value in {ENGINE / file}")
    return eval(match.group(1), {"__builtins__": {}})  # digits, spaces, * and + only (the pattern above)


def written_out(text, path, name, body):
    """`text` (a shader's source, read from `path`) with the lines between its `// BEGIN name` and `// END name`
    lines replaced by body(indent), indent being the BEGIN line's."""
    begin_line = f"// BEGIN {name}: written by tools/codegen/{Path(sys.argv[0]).name}"
    begin, end = text.find(begin_line), text.find(f"// END {name}")
    if begin < 0 or end < begin:
        sys.exit(f"{Path(sys.argv[0]).name}: {path} has no `{begin_line}` line followed by `// END {name}`")
    indent = text[text.rfind("\n", 0, begin) + 1:begin]
    body_start = text.index("\n", begin) + 1
    return text[:body_start] + body(indent) + text[text.rfind("\n", 0, end) + 1:]


def write_or_check(files):
    """Writes `files` (path: text), or with `--check` exits 1 naming those whose text differs."""
    if "--check" in sys.argv[1:]:
        stale = [path for path, text in files.items() if not path.exists() or path.read_text() != text]
        if stale:
            names = ", ".join(str(p.relative_to(ROOT)) for p in stale)
            print(f"{names}: not what tools/codegen/{Path(sys.argv[0]).name} writes: run it and commit the shaders")
            sys.exit(1)
        return
    for path, text in files.items():
        path.write_text(text)
