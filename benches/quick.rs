//! `cargo bench`: the benchmark harness's quick mode (`raypatch-bench --quick`), results in
//! target/bench-quick. The full sweep is `cargo run --release -p raypatch-bench -- --out DIR`.

use std::path::Path;
use std::process::ExitCode;

fn main() -> ExitCode {
    let out = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/bench-quick");
    let options = raypatch_bench::Options {
        quick: true,
        out,
        adapter: None,
        matmul: None,
        without_subgroups: false,
        rays_on_host: false,
        repeats: None,
        repeat_seconds: None,
        max_render_seconds: None,
        max_reference_gmac: None,
        pytorch: true,
        pytorch_device: None,
        pytorch_compile: false,
        models: Vec::new(),
        scene: None,
        only: Vec::new(),
        sizes: Vec::new(),
        views: Vec::new(),
        command: "cargo bench".into(),
    };
    match raypatch_bench::run(&options) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("raypatch-bench: {e:#}");
            ExitCode::FAILURE
        }
    }
}
