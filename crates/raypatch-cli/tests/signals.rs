//! render-frame stopped by SIGINT or SIGTERM mid-run (issue 40): it exits at once with 130 or 143 and leaves
//! nothing behind, for every kind of output: a PNG, a new folder of PNGs, an MP4, a GIF, raw tensors; and files
//! that were there before are as they were. The signal is sent once the run's first temporary exists (the
//! outputs are being written), and also right after the start (the model and GPU still loading).

#![cfg(unix)]

mod common;

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::files;
use tempfile::TempDir;

/// Long runs of the bundled model: each would take a minute or more on lavapipe if not stopped.
const RUNS: [(&str, &[&str]); 5] = [
    ("png", &["--repeat", "100000", "--out", "render.png"]),
    ("folder", &["--orbit-frames", "5000", "--out", "turntable"]),
    ("mp4", &["--motion", "orbit", "--frames", "5000", "--out", "orbit.mp4"]),
    ("gif", &["--motion", "orbit", "--frames", "5000", "--out", "orbit.gif"]),
    ("raw", &["--outputs", "rgb", "--out-raw", "raw.safetensors", "--repeat", "100000", "--out", "r.png"]),
];

fn start(dir: &Path, args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_render-frame"))
        .args(args)
        .arg("--quiet")
        .current_dir(dir)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Whether one of render-frame's temporaries exists under `dir` (in it or in a folder the run made).
fn writing(dir: &Path) -> bool {
    files(dir).iter().any(|f| f.contains(".raypatch-"))
}

fn signal(child: &Child, signal: i32) {
    assert_eq!(unsafe { libc::kill(child.id() as i32, signal) }, 0);
}

/// Waits for the child's exit (at most `limit`) and gives its code and stderr.
fn exit_within(mut child: Child, limit: Duration) -> (i32, String) {
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut stderr = String::new();
            std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut stderr).unwrap();
            return (status.code().unwrap_or(-1), stderr);
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            panic!("render-frame did not exit within {limit:?} of the signal");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn a_signal_mid_write_exits_at_once_and_leaves_nothing() {
    for (i, (kind, args)) in RUNS.iter().enumerate() {
        let (sig, code) = if i % 2 == 0 { (libc::SIGINT, 130) } else { (libc::SIGTERM, 143) };
        let dir = TempDir::new().unwrap();
        let d = dir.path();
        // A file of the user's that the run would replace, and one beside it.
        std::fs::write(d.join("render.png"), b"kept").unwrap();
        std::fs::write(d.join("notes.txt"), b"mine").unwrap();
        let before = files(d);
        let child = start(d, args);
        let started = Instant::now();
        while !writing(d) {
            assert!(started.elapsed() < Duration::from_secs(120), "{kind}: no temporary appeared");
            std::thread::sleep(Duration::from_millis(10));
        }
        // Let a few frames stream into the temporaries.
        std::thread::sleep(Duration::from_millis(300));
        signal(&child, sig);
        let (exit, stderr) = exit_within(child, Duration::from_secs(5));
        assert_eq!(exit, code, "{kind}: {stderr}");
        assert!(!stderr.contains("panicked"), "{kind}: {stderr}");
        assert_eq!(files(d), before, "{kind}: something was left behind");
        assert_eq!(std::fs::read(d.join("render.png")).unwrap(), b"kept", "{kind}");
    }
}

#[test]
fn a_signal_before_any_output_exits_with_nothing_written() {
    for (sig, code) in [(libc::SIGINT, 130), (libc::SIGTERM, 143)] {
        let dir = TempDir::new().unwrap();
        let d = dir.path();
        let child = start(d, RUNS[2].1);
        std::thread::sleep(Duration::from_millis(300));
        signal(&child, sig);
        let (exit, stderr) = exit_within(child, Duration::from_secs(5));
        assert_eq!(exit, code, "{stderr}");
        assert_eq!(files(d), Vec::<String>::new());
    }
}
