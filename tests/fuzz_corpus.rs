//! The fuzz targets' entry points (`raypatch::fuzzing`, run for real by `cargo fuzz`, fuzz/README.md) on
//! stable Rust in every test run: the good inputs they start from are accepted, every input saved in
//! fuzz/corpus (crashes found by fuzzing belong there) and a few thousand deterministic mutations of the
//! good inputs (truncations, bit flips, overwritten bytes) are handled without a panic.

use std::path::{Path, PathBuf};

use raypatch::fuzzing;

type Target = fn(&[u8]) -> bool;

const TARGETS: [(&str, Target); 6] = [
    ("safetensors_file", fuzzing::safetensors_file),
    ("model_file", fuzzing::model_file),
    ("scene_file", fuzzing::scene_file),
    ("frames_folder", fuzzing::frames_folder),
    ("checkpoint_file", fuzzing::checkpoint_file),
    ("checkpoint_pickle", fuzzing::checkpoint_pickle),
];

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The good inputs each target starts from: the golden models and scenes, the committed frame seed.
fn seeds(target: &str) -> Vec<PathBuf> {
    let golden = |file: &str| root().join("assets/golden/rpsrt_k4").join(file);
    match target {
        "safetensors_file" | "model_file" => vec![golden("model.safetensors")],
        "scene_file" => vec![golden("scene.safetensors"), root().join("assets/scenes/scene-2000000.safetensors")],
        // A Lightning checkpoint of the golden rpsrt_k4 model (tools/tests/test_checkpoint_reader.py's "views"
        // variant), and its pickle.
        "checkpoint_file" | "checkpoint_pickle" | "frames_folder" => {
            vec![root().join("fuzz/corpus").join(target).join("seed")]
        }
        other => panic!("no seed for the fuzz target {other}"),
    }
}

/// A small deterministic generator (xorshift), so a failure names a reproducible case.
struct Rng(u64);
impl Rng {
    fn next(&mut self, below: usize) -> usize {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 % below.max(1) as u64) as usize
    }
}

fn mutations(seed: &[u8], count: usize) -> Vec<Vec<u8>> {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    (0..count)
        .map(|i| {
            let mut bytes = seed.to_vec();
            match i % 4 {
                0 => bytes.truncate(rng.next(seed.len())),
                1 => {
                    let at = rng.next(bytes.len());
                    bytes[at] ^= 1 << rng.next(8);
                }
                // Bytes early in the file: the safetensors header, the JSON and the PNG header.
                2 => {
                    let at = rng.next(bytes.len().min(600));
                    bytes[at] = [b'9', b'0', b'-', b'"', b'e', 0xff, 0][rng.next(7)];
                }
                _ => {
                    let at = rng.next(bytes.len().min(40));
                    bytes[at..(at + 8).min(seed.len())].fill(0xff);
                }
            }
            bytes
        })
        .collect()
}

#[test]
fn the_fuzz_targets_accept_their_seeds() {
    for (name, target) in TARGETS {
        for seed in seeds(name) {
            let bytes = std::fs::read(&seed).unwrap();
            assert!(target(&bytes), "{name}: the seed {} is rejected", seed.display());
        }
    }
}

#[test]
fn the_fuzz_targets_survive_the_corpus_and_mutations_of_their_seeds() {
    for (name, target) in TARGETS {
        let corpus = root().join("fuzz/corpus").join(name);
        let mut inputs: Vec<Vec<u8>> = std::fs::read_dir(&corpus)
            .map(|entries| entries.flatten().map(|e| std::fs::read(e.path()).unwrap()).collect())
            .unwrap_or_default();
        for seed in seeds(name) {
            inputs.extend(mutations(&std::fs::read(seed).unwrap(), 300));
        }
        for (i, input) in inputs.iter().enumerate() {
            let started = std::time::Instant::now();
            let outcome = std::panic::catch_unwind(|| target(input));
            assert!(outcome.is_ok(), "{name}: input {i} ({} bytes) panicked", input.len());
            // As .ci/fuzz.sh's -timeout: no input may take long (issue 50: a search the input made quadratic).
            // Generous: a guard against a hang, not a timing.
            let took = started.elapsed();
            assert!(took.as_secs() < 20, "{name}: input {i} ({} bytes) took {took:?}", input.len());
        }
    }
}
