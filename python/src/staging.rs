//! Output files for the package and its Ray CLI through raypatch's own writer (src/output): the output plan's
//! checks, outputs staged and committed all or none (one temporary per file, flushed to disk at the commit),
//! and the signal clean-up. `raypatch/output.py` gives them their Python names.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use pyo3::prelude::*;
use pyo3::types::PyBytes;

use crate::{image_of, to_py};

/// Outputs being written, all or none: `raypatch::Staged`. A context manager: left without `commit` (an
/// error), its temporaries and the folders made for them are removed.
#[pyclass(module = "raypatch._raypatch")]
#[derive(Default)]
pub struct Staged {
    inner: raypatch::Staged,
}

#[pymethods]
impl Staged {
    #[new]
    fn new() -> Staged {
        Staged::default()
    }

    /// The outputs of a run checked (as [`check_outputs`]) and begun: the new folders made.
    #[staticmethod]
    #[pyo3(signature = (files, folders=Vec::new(), inputs=Vec::new()))]
    fn planned(files: Named, folders: Named, inputs: Named) -> PyResult<Staged> {
        Ok(Staged { inner: output_files(&files, &folders, &inputs)?.begin().map_err(to_py)? })
    }

    fn __enter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    #[pyo3(signature = (*_exc))]
    fn __exit__(&mut self, _exc: &Bound<'_, pyo3::types::PyTuple>) {
        self.discard();
    }

    /// The temporary that becomes `dest` at the commit, created empty, for a writer that opens it by name.
    fn file(&mut self, dest: PathBuf) -> PyResult<OsString> {
        Ok(self.inner.temporary(&dest).map_err(to_py)?.into_os_string())
    }

    /// Writes `data` as the output `dest`.
    fn write(&mut self, py: Python<'_>, dest: PathBuf, data: &[u8]) -> PyResult<()> {
        let inner = &mut self.inner;
        py.detach(|| inner.write(&dest, data)).map_err(to_py)
    }

    /// A new temporary folder whose files (subfolders included) become `dest`'s at the commit.
    fn folder(&mut self, dest: PathBuf) -> PyResult<OsString> {
        Ok(self.inner.stage_folder(&dest).map_err(to_py)?.into_os_string())
    }

    /// Makes a folder for outputs (its parent must exist); removed again, when empty, without a commit.
    fn new_folder(&mut self, path: PathBuf) -> PyResult<()> {
        self.inner.create_folder(&path).map_err(to_py)
    }

    /// Flushes every output to disk and moves them all into place, all or none.
    fn commit(&mut self, py: Python<'_>) -> PyResult<()> {
        let staged = std::mem::take(&mut self.inner);
        py.detach(move || staged.commit()).map_err(to_py)
    }

    /// Removes every temporary and the folders made for them.
    fn discard(&mut self) {
        self.inner = raypatch::Staged::default();
    }
}

type Named = Vec<(String, PathBuf)>;

/// Checks a run's outputs before anything is written (`raypatch::OutputFiles::check`): `files`, `folders` to
/// make for them and `inputs`, each (flag, path).
#[pyfunction]
#[pyo3(signature = (files, folders=Vec::new(), inputs=Vec::new()))]
pub fn check_outputs(files: Named, folders: Named, inputs: Named) -> PyResult<()> {
    output_files(&files, &folders, &inputs).map(|_| ())
}

fn output_files(files: &Named, folders: &Named, inputs: &Named) -> PyResult<raypatch::OutputFiles> {
    raypatch::OutputFiles::check(&borrowed(files), &borrowed(folders), &borrowed(inputs)).map_err(to_py)
}

fn borrowed(list: &Named) -> Vec<(&str, &Path)> {
    list.iter().map(|(flag, path)| (flag.as_str(), path.as_path())).collect()
}

/// A unique name beside `path`, `.NAME.raypatch-PID-N.EXT`, as raypatch names its temporaries.
#[pyfunction]
pub fn sibling(path: PathBuf, ext: &str) -> OsString {
    raypatch::sibling(&path, ext).into_os_string()
}

/// A `[height, width, 3]` f32 image in [0, 1] as the bytes of a PNG file.
#[pyfunction]
pub fn encode_png<'py>(py: Python<'py>, rgb: &[u8], width: i64, height: i64) -> PyResult<Bound<'py, PyBytes>> {
    let image = image_of("rgb", rgb, width, height)?;
    let png = py.detach(|| image.encode_png()).map_err(to_py)?;
    Ok(PyBytes::new(py, &png))
}

/// The program's name for the line a stop prints, and what to call before the process ends.
static STOPPING: Mutex<Option<(String, Option<Py<PyAny>>)>> = Mutex::new(None);

const SIGNALS: [&str; 3] = ["SIGINT", "SIGTERM", "SIGHUP"];

/// From now on SIGINT, SIGTERM and SIGHUP end the process through [`stop`]. Python's own handlers (the
/// interpreter, not a thread of raypatch's, owns a Python process's signals); call it again after anything
/// that sets its own (Ray sets SIGTERM's). `before_exit` is kept from an earlier call where None.
#[pyfunction]
#[pyo3(signature = (prog, before_exit=None))]
pub fn stop_on_signals(py: Python<'_>, prog: String, before_exit: Option<Py<PyAny>>) -> PyResult<()> {
    {
        let mut stopping = STOPPING.lock().unwrap_or_else(|e| e.into_inner());
        let before_exit = before_exit.or_else(|| stopping.take().and_then(|(_, kept)| kept));
        *stopping = Some((prog, before_exit));
    }
    let signal = py.import("signal")?;
    let handler = wrap_pyfunction!(stop, py)?;
    for name in SIGNALS {
        if let Ok(number) = signal.getattr(name) {
            signal.call_method1("signal", (number, &handler))?;
        }
    }
    Ok(())
}

/// Ends the process as signal `signum` does (`raypatch::stop`: every temporary and new folder not committed
/// removed, exit code 128 + signum), printing "PROG: stopped by NAME" and calling `before_exit` (ending Ray's
/// processes) first. A signal handler, and for a signal caught elsewhere.
#[pyfunction]
#[pyo3(signature = (signum, _frame=None))]
pub fn stop(py: Python<'_>, signum: i32, _frame: Option<Bound<'_, PyAny>>) -> PyResult<()> {
    let signal = py.import("signal")?;
    // A second signal while stopping would re-enter this handler on the same thread.
    let ignore = signal.getattr("SIG_IGN")?;
    for name in SIGNALS {
        if let Ok(number) = signal.getattr(name) {
            signal.call_method1("signal", (number, &ignore))?;
        }
    }
    let name: String = signal.getattr("Signals")?.call1((signum,))?.getattr("name")?.extract()?;
    let stopping = STOPPING.lock().unwrap_or_else(|e| e.into_inner()).take();
    let (prog, before_exit) = stopping.unwrap_or_else(|| ("raypatch".to_string(), None));
    raypatch::stop(signum, || {
        eprintln!("{prog}: stopped by {name}");
        if let Some(before_exit) = before_exit {
            // Ending anyway: what it could not stop, it could not stop.
            let _ = before_exit.call0(py);
        }
    })
}
