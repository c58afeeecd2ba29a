"""Output files of the Ray CLI (raypatch.distributed, raypatch.evaluate), written by render-frame's own writer
(the Rust crate's src/output, through the extension module), so that both behave alike:

- `check_outputs(files, folders, inputs)`: a run's outputs checked before anything is written, each a (flag,
  path): no output is an input (the same file by any path, hard links and symlinks included) or lies in an
  input folder, no two outputs are one file, every folder exists or can be made, every path takes a file.
- `Staged`: outputs written all or none. Each output is one temporary beside it, `.NAME.raypatch-PID-N.tmp`
  (`file`, `write`; or a folder whose files are merged into a destination folder, `folder`), until `commit`
  flushes them to disk and moves them all into place; an existing file is first moved aside
  (`.NAME.raypatch-PID-N.bak`) and put back if a later move fails. Left without a commit (a context manager),
  nothing of it stays. Temporaries of runs killed outright are removed by the next run writing beside them.
- `stop_on_signals(prog, before_exit)`: from then on SIGINT, SIGTERM and SIGHUP remove every temporary not
  committed (a commit under way is finished first), print "PROG: stopped by NAME", call `before_exit` (ending
  Ray's processes, within STOP_SECONDS) and end the process with 128 + the signal's number. `stop(signum)` does
  it for a signal caught elsewhere.
"""

from ._raypatch import (MAX_NAME_BYTES, STOP_SECONDS, TEMP_MARK, Staged, check_outputs, sibling, stop,
                        stop_on_signals)

__all__ = ["MAX_NAME_BYTES", "STOP_SECONDS", "TEMP_MARK", "Staged", "check_outputs", "sibling", "stop",
           "stop_on_signals"]
