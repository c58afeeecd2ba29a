//! Output files, for every surface (render-frame, its viewer, the Python package and its Ray CLI), written so
//! that nothing is lost: a run's outputs are checked before any is written (`plan.rs`: no output is an input
//! or another output, every folder exists or can be made), all are written to temporaries in their own
//! folders, and only when every write succeeded are they moved into place, all or none (`staged.rs`). A path
//! that exists must be a regular file: a symlink, FIFO, device or folder there is refused, never replaced.
//! Temporaries are unique per process and listed in one registry of the process, which a signal empties before
//! the process ends (`signals.rs`); ones left by a killed run (SIGKILL, a power cut) are removed later, and
//! files it had moved aside are put back.

mod plan;
mod signals;
mod staged;

pub use plan::{same_file, OutputFiles};
pub use signals::{clean_up_on_signals, clean_up_on_signals_then, stop, STOP_SECONDS};
pub use staged::{
    check_output_path, folder_of, sibling, write_all_atomic, write_atomic, Staged, MAX_NAME_BYTES, TEMP_MARK,
};
