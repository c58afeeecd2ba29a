//! The process's registry of what it has on disk that is not an output yet ([`Pending`]), and how a signal ends
//! the process with it emptied. Every program ends through here: render-frame ([`clean_up_on_signals`]), its
//! viewer ([`clean_up_on_signals_then`]) and the Python package's Ray CLI, whose handlers call [`stop`].

use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

use crate::error::Result;

/// What the process has on disk that is not yet an output: temporaries (files, and folders of files) and the
/// new folders made for outputs. Whoever holds the lock may change the disk: [`Staged`](super::Staged)
/// creates, removes and commits its files under it, so a signal's clean-up never runs half-way through a
/// commit, and nothing is created after it (the clean-up keeps the lock until the process ends).
pub(super) struct Pending {
    temporaries: Vec<PathBuf>,
    folders: Vec<PathBuf>,
}

static PENDING: Mutex<Pending> = Mutex::new(Pending { temporaries: Vec::new(), folders: Vec::new() });

pub(super) fn pending() -> MutexGuard<'static, Pending> {
    // A panic while the lock was held leaves the lists as they were: still right to use.
    PENDING.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

impl Pending {
    pub(super) fn add_temporary(&mut self, tmp: PathBuf) {
        self.temporaries.push(tmp);
    }

    pub(super) fn forget(&mut self, tmp: &Path) {
        self.temporaries.retain(|t| t != tmp);
    }

    pub(super) fn add_folder(&mut self, folder: PathBuf) {
        self.folders.push(folder);
    }

    pub(super) fn forget_folder(&mut self, folder: &Path) {
        self.folders.retain(|f| f != folder);
    }

    #[cfg(test)]
    pub(super) fn holds(&self, path: &Path) -> bool {
        self.temporaries.iter().chain(&self.folders).any(|p| p.starts_with(path))
    }

    /// Removes every temporary, the newest first, then every folder made for outputs (only if empty).
    fn remove_all(&mut self) {
        for tmp in self.temporaries.drain(..).rev() {
            remove_temporary(&tmp);
        }
        for folder in self.folders.drain(..).rev() {
            let _ = std::fs::remove_dir(folder);
        }
    }
}

/// Removes a temporary: a file, or a folder with everything in it. A folder is tried again for a second
/// while something else still adds files to it (Ray workers writing a scene's views into a run's folder).
pub(super) fn remove_temporary(path: &Path) {
    let Ok(meta) = std::fs::symlink_metadata(path) else { return };
    if !meta.is_dir() {
        let _ = std::fs::remove_file(path);
        return;
    }
    for _ in 0..50 {
        match std::fs::remove_dir_all(path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => std::thread::sleep(Duration::from_millis(20)),
            _ => return,
        }
    }
}

/// How long the last step of [`stop`] may take before the process ends anyway.
pub const STOP_SECONDS: u64 = 10;

/// Ends the process as `signal` would, with 128 + its number (130, 143, 129, as a shell reports a process the
/// signal killed): removes every temporary and new folder not yet committed, keeps the registry so that
/// nothing is created or moved into place afterwards (a commit under way is finished first: this waits for
/// it), then runs `last` (a message, stopping helper processes), which gets [`STOP_SECONDS`].
pub fn stop(signal: i32, last: impl FnOnce()) -> ! {
    let mut held = pending();
    held.remove_all();
    let _ = std::thread::Builder::new().name("raypatch-stop".into()).spawn(move || {
        std::thread::sleep(Duration::from_secs(STOP_SECONDS));
        exit_now(128 + signal)
    });
    last();
    exit_now(128 + signal)
}

/// Ends the process at once: no atexit handlers, which could wait on the GPU driver other threads are in.
fn exit_now(code: i32) -> ! {
    #[cfg(unix)]
    unsafe {
        libc::_exit(code)
    }
    #[cfg(not(unix))]
    std::process::exit(code)
}

/// From now on SIGINT and SIGTERM (and SIGHUP: a closed terminal) end the process at once through [`stop`]:
/// a stopped run leaves nothing behind and never a half-written output. For programs like `render-frame`; a
/// library's caller keeps its own handling.
pub fn clean_up_on_signals() -> Result<()> {
    on_signals(|signal| stop(signal, || {}))
}

/// As [`clean_up_on_signals`], for a program that ends itself (a server finishing its connections): the first
/// signal removes what is not committed, keeps the registry (nothing is written afterwards) and calls
/// `then(signal)`, which asks the program to end, with 128 + the signal's number; a second signal ends the
/// process at once.
pub fn clean_up_on_signals_then(then: impl FnOnce(i32) + Send + 'static) -> Result<()> {
    on_signals(move |signal| {
        let mut held = pending();
        held.remove_all();
        std::mem::forget(held);
        then(signal)
    })
}

/// Runs `first` on a thread of its own at the first of SIGINT, SIGTERM and SIGHUP, and ends the process at a
/// second.
#[cfg(unix)]
fn on_signals(first: impl FnOnce(i32) + Send + 'static) -> Result<()> {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let cannot = |e| crate::error::Error::io(Path::new("signals"), "cannot handle", e);
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP]).map_err(cannot)?;
    std::thread::Builder::new()
        .name("raypatch-signals".into())
        .spawn(move || {
            let mut received = signals.forever();
            if let Some(signal) = received.next() {
                first(signal);
            }
            if let Some(signal) = received.next() {
                exit_now(128 + signal);
            }
        })
        .map_err(cannot)?;
    Ok(())
}

/// Elsewhere the platform's default (the process ends); temporaries are removed by a later run.
#[cfg(not(unix))]
fn on_signals(_first: impl FnOnce(i32) + Send + 'static) -> Result<()> {
    Ok(())
}
