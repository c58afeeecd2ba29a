//! No two source files of a crate use each other, directly or around a circle, and no two of its top-level
//! modules (a folder such as `kernels/` counting as one): each file's `crate::` and `super::` paths (outside
//! comments) name the files it builds on, and those must form floors (ARCHITECTURE.md). A module's own
//! submodules declared with `mod` are not uses; the crate root (lib.rs, main.rs), which only declares and
//! re-exports, is left out.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Every crate's `src` folder.
fn crate_sources() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut sources = vec![root.join("src")];
    for entry in std::fs::read_dir(root.join("crates")).unwrap() {
        let src = entry.unwrap().path().join("src");
        if src.is_dir() {
            sources.push(src);
        }
    }
    sources
}

fn rust_files(dir: &Path, found: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, found);
        } else if path.extension().is_some_and(|e| e == "rs") {
            found.push(path);
        }
    }
}

/// The module path of a file under `src` (`kernels/mod.rs` -> ["kernels"], `kernels/conv.rs` -> ["kernels", "conv"]).
fn module_of(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).unwrap().with_extension("");
    let mut parts: Vec<String> = rel.iter().map(|p| p.to_string_lossy().into_owned()).collect();
    if parts.last().is_some_and(|p| p == "mod" || p == "lib" || p == "main") {
        parts.pop();
    }
    parts
}

/// The file that defines the longest prefix of `path` that is a module.
fn file_of(src: &Path, path: &[String]) -> PathBuf {
    for n in (1..=path.len()).rev() {
        let dir: PathBuf = path[..n].iter().collect();
        for candidate in [src.join(&dir).with_extension("rs"), src.join(&dir).join("mod.rs")] {
            if candidate.is_file() {
                return candidate;
            }
        }
    }
    src.join("lib.rs")
}

/// The text without comments (line comments, doc comments included) and string literals.
fn code_of(text: &str) -> String {
    let mut code = String::with_capacity(text.len());
    for line in text.lines() {
        let mut in_string = false;
        let mut prev = ' ';
        for (i, c) in line.char_indices() {
            if !in_string && line[i..].starts_with("//") {
                break;
            }
            if c == '"' && prev != '\\' {
                in_string = !in_string;
            } else if !in_string {
                code.push(c);
            }
            prev = c;
        }
        code.push('\n');
    }
    code
}

/// The paths after `start` in `code`: `a::b::{c, d::e}` gives [a, b, c], [a, b, d, e].
fn paths_at(code: &str, start: usize) -> Vec<Vec<String>> {
    fn parse(chars: &[char], mut i: usize, prefix: Vec<String>, out: &mut Vec<Vec<String>>) -> usize {
        let mut path = prefix;
        loop {
            let begin = i;
            while i < chars.len() && (chars[i].is_alphanumeric() || chars[i] == '_') {
                i += 1;
            }
            if i > begin {
                path.push(chars[begin..i].iter().collect());
            }
            if chars.get(i) == Some(&':') && chars.get(i + 1) == Some(&':') {
                i += 2;
                if chars.get(i) == Some(&'{') {
                    i += 1;
                    loop {
                        while chars.get(i).is_some_and(|c| c.is_whitespace() || *c == ',') {
                            i += 1;
                        }
                        if i >= chars.len() || chars[i] == '}' {
                            return i + 1;
                        }
                        i = parse(chars, i, path.clone(), out);
                    }
                }
                continue;
            }
            out.push(path);
            return i;
        }
    }
    let chars: Vec<char> = code[start..].chars().take(2000).collect();
    let mut out = Vec::new();
    parse(&chars, 0, Vec::new(), &mut out);
    out
}

/// file -> the files its `crate::` and `super::` paths name.
fn uses(src: &Path) -> BTreeMap<PathBuf, BTreeSet<PathBuf>> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let mut graph = BTreeMap::new();
    for file in files {
        let module = module_of(src, &file);
        let code = code_of(&std::fs::read_to_string(&file).unwrap());
        let mut used = BTreeSet::new();
        for (anchor, base) in [("crate::", Vec::new()), ("super::", module[..module.len().saturating_sub(1)].to_vec())]
        {
            // `super::` of a mod.rs names its parent's parent only from a child file: here the module itself
            // is the file's, so its parent is one level up either way.
            for (at, _) in code.match_indices(anchor) {
                let before = code[..at].chars().last();
                if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':') {
                    continue; // part of a longer path (`raypatch_engine::crate::`, `super::super::`)
                }
                for path in paths_at(&code, at + anchor.len()) {
                    let full: Vec<String> = base.iter().cloned().chain(path).collect();
                    let target = file_of(src, &full);
                    let root = target.file_name().is_some_and(|n| n == "lib.rs" || n == "main.rs")
                        && target.parent() == Some(src);
                    if target != file && !root {
                        used.insert(target);
                    }
                }
            }
        }
        graph.insert(file, used);
    }
    graph
}

/// The strongly connected components of more than one file (Tarjan).
fn circles(graph: &BTreeMap<PathBuf, BTreeSet<PathBuf>>) -> Vec<Vec<PathBuf>> {
    struct State<'a> {
        graph: &'a BTreeMap<PathBuf, BTreeSet<PathBuf>>,
        index: BTreeMap<&'a PathBuf, usize>,
        low: BTreeMap<&'a PathBuf, usize>,
        stack: Vec<&'a PathBuf>,
        on_stack: BTreeSet<&'a PathBuf>,
        found: Vec<Vec<PathBuf>>,
    }
    fn visit<'a>(s: &mut State<'a>, v: &'a PathBuf) {
        let n = s.index.len();
        s.index.insert(v, n);
        s.low.insert(v, n);
        s.stack.push(v);
        s.on_stack.insert(v);
        for w in s.graph.get(v).into_iter().flatten() {
            let Some((w, _)) = s.graph.get_key_value(w) else { continue };
            if !s.index.contains_key(w) {
                visit(s, w);
                let low = s.low[v].min(s.low[w]);
                s.low.insert(v, low);
            } else if s.on_stack.contains(w) {
                let low = s.low[v].min(s.index[w]);
                s.low.insert(v, low);
            }
        }
        if s.low[v] == s.index[v] {
            let mut component = Vec::new();
            while let Some(w) = s.stack.pop() {
                s.on_stack.remove(w);
                component.push(w.clone());
                if w == v {
                    break;
                }
            }
            if component.len() > 1 {
                component.sort();
                s.found.push(component);
            }
        }
    }
    let mut state = State {
        graph,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        found: Vec::new(),
    };
    for v in graph.keys() {
        if !state.index.contains_key(v) {
            visit(&mut state, v);
        }
    }
    state.found
}

#[test]
fn no_source_files_use_each_other() {
    let mut report = Vec::new();
    for src in crate_sources() {
        for circle in circles(&uses(&src)) {
            let names: Vec<String> =
                circle.iter().map(|f| f.strip_prefix(&src).unwrap().display().to_string()).collect();
            report.push(format!("{}: {}", src.display(), names.join(" <-> ")));
        }
    }
    assert!(report.is_empty(), "files that use each other, directly or around a circle:\n{}", report.join("\n"));
}

#[test]
fn the_checker_finds_paths_and_circles() {
    let paths = paths_at("a::b::{c, d::{e, f}}, g;", 0);
    let joined: Vec<String> = paths.iter().map(|p| p.join("::")).collect();
    assert_eq!(joined, ["a::b::c", "a::b::d::e", "a::b::d::f"]);
    assert_eq!(code_of("let x = \"crate::a\"; // crate::b\ncrate::c"), "let x = ; \ncrate::c\n");
    let graph: BTreeMap<PathBuf, BTreeSet<PathBuf>> =
        [("a", vec!["b"]), ("b", vec!["c"]), ("c", vec!["a"]), ("d", vec!["a"])]
            .into_iter()
            .map(|(f, to)| (PathBuf::from(f), to.into_iter().map(PathBuf::from).collect()))
            .collect();
    assert_eq!(circles(&graph), [vec![PathBuf::from("a"), PathBuf::from("b"), PathBuf::from("c")]]);
}
