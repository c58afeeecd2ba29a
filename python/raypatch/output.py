"""Output files of the Ray CLI (raypatch.distributed, raypatch.evaluate), written all or none as render-frame
writes its own (src/output.rs). Each output is a temporary beside it, `.NAME.raypatch-PID-N.tmp` (a file, or a
folder whose files are merged into a destination folder), until `Staged.commit` moves them all into place; an
existing file is first moved aside (`.NAME.raypatch-PID-N.bak`) and put back if a later move fails. Every
temporary is listed in one registry of the process, which `stop_on_signals` empties when SIGINT, SIGTERM or
SIGHUP arrives, ending the process with 128 + the signal's number; a commit under way is finished first.
Temporaries of runs killed outright are removed by the next run writing beside them (render-frame's too: the
names are the same)."""

from __future__ import annotations

import itertools
import os
import re
import shutil
import signal
import stat
import time
import threading
from typing import Callable, Iterable, List, Optional, Sequence, Tuple

from ._raypatch import FileError
from ._text import path_text

TEMP_MARK = ".raypatch-"
# The longest file name most file systems take (bytes).
MAX_NAME_BYTES = 255
_TEMPORARY = re.compile(r"^\.(.*)" + re.escape(TEMP_MARK) + r"(\d+)-\d+\.(tmp|bak)$", re.S)
_counter = itertools.count()


class _Pending:
    """What the process has on disk that is not an output yet, oldest first: temporaries (files and folders)
    and folders made for outputs; and, while a commit moves files, the signal that waits for it."""

    def __init__(self) -> None:
        self.temporaries: List[str] = []
        self.folders: List[str] = []
        self.committing = False
        self.signal: Optional[int] = None
        self.prog = "raypatch"
        self.before_exit: Optional[Callable[[], None]] = None

    def remove_all(self) -> None:
        for tmp in reversed(self.temporaries):
            _remove(tmp)
        for folder in reversed(self.folders):
            try:
                os.rmdir(folder)
            except OSError:
                pass  # not empty: something else was put there
        self.temporaries.clear()
        self.folders.clear()


_pending = _Pending()


def _remove(path: str) -> None:
    """Removes a file, or a folder and what is in it; tries again while other processes (Ray workers still
    finishing a view) add files to the folder."""
    for _ in range(50):
        try:
            if stat.S_ISDIR(os.lstat(path).st_mode):
                shutil.rmtree(path)
            else:
                os.unlink(path)
        except FileNotFoundError:
            return
        except OSError:
            time.sleep(0.02)
            continue
        return


# How long `before_exit` may take before the process ends anyway.
BEFORE_EXIT_SECONDS = 10.0


def stop_on_signals(prog: str, before_exit: Optional[Callable[[], None]] = None) -> None:
    """From now on SIGINT, SIGTERM and SIGHUP end the process at once with 128 + the signal's number (130, 143,
    129) after removing every temporary of this module's writers (a stopped run leaves nothing behind) and
    calling `before_exit` (ending Ray's processes), which gets BEFORE_EXIT_SECONDS. For programs (`python -m
    raypatch.distributed`); call it again after anything that sets its own handlers (Ray sets SIGTERM's)."""
    _pending.prog = prog
    _pending.before_exit = before_exit or _pending.before_exit
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, _on_signal)


def _on_signal(signum: int, frame) -> None:
    if _pending.committing:
        _pending.signal = signum  # the commit ends the process once its moves are all done or all undone
        return
    stop(signum)


def stop(signum: int) -> None:
    """Ends the process as `signum` does once stop_on_signals was called (for a signal caught elsewhere)."""
    for other in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(other, signal.SIG_IGN)
    _pending.remove_all()
    os.write(2, f"{_pending.prog}: stopped by {signal.Signals(signum).name}\n".encode())
    if _pending.before_exit is not None:
        threading.Timer(BEFORE_EXIT_SECONDS, os._exit, (128 + signum,)).start()
        try:
            _pending.before_exit()
        except Exception:  # ending anyway: what it could not stop, it could not stop
            pass
    # _exit: no atexit handlers, which could wait on the GPU driver or on what before_exit could not stop.
    os._exit(128 + signum)


def sibling(path: str, ext: str) -> str:
    """A unique name in `path`'s folder, `.NAME.raypatch-PID-N.EXT`, NAME shortened to fit MAX_NAME_BYTES."""
    folder, name = os.path.split(os.path.normpath(path))
    tail = f"{TEMP_MARK}{os.getpid()}-{next(_counter)}.{ext}"
    name = os.fsdecode(os.fsencode(name)[:MAX_NAME_BYTES - 1 - len(tail)])
    return os.path.join(folder, f".{name}{tail}")


def remove_stale(folder: str) -> None:
    """Cleans up after runs in `folder` whose process is gone (killed without a chance to clean up): removes
    their temporaries, and puts each file they had moved aside back where nothing took its place. Where process
    ids cannot be checked (no /proc), files older than a day count as stale."""
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return
    proc = os.path.exists("/proc/self")
    for entry in entries:
        match = _TEMPORARY.match(entry.name)
        if match is None:
            continue
        original, pid, ext = match.group(1), int(match.group(2)), match.group(3)
        try:
            age = time.time() - entry.stat(follow_symlinks=False).st_mtime
        except OSError:
            continue
        alive = (pid == os.getpid() or os.path.exists(f"/proc/{pid}")) if proc else age < 24 * 3600
        if alive or entry.is_symlink():
            continue
        if ext == "tmp":
            _remove(entry.path)
        elif original and len(os.fsencode(entry.name)) + 3 < MAX_NAME_BYTES:  # NAME was not shortened
            target = os.path.join(folder, original)
            if os.path.lexists(target):
                _remove(entry.path)
            else:
                try:
                    os.rename(entry.path, target)
                except OSError:
                    pass  # left for a later run: a clean-up never stops this one


def _file_error(path: str, action: str, error: OSError) -> FileError:
    return FileError(f"{path_text(path)}: {action}: {error.strerror or error}")


def check_output_path(flag: str, path: str) -> None:
    """Refuses a path that cannot take an output file: its folder must exist, and anything there must be a
    regular file (a symlink, folder, FIFO or device is never replaced)."""
    name = os.path.basename(path)
    if not name or len(os.fsencode(name)) > MAX_NAME_BYTES:
        raise FileError(f"{flag} {path_text(path)}: expected a file name of at most {MAX_NAME_BYTES} bytes")
    try:
        mode = os.lstat(path).st_mode
    except OSError:
        mode = None
    if mode is not None and not stat.S_ISREG(mode):
        raise FileError(f"{flag} {path_text(path)}: is {_kind(mode)}; only regular files are replaced")
    folder = os.path.dirname(path) or "."
    if not os.path.isdir(folder):
        raise FileError(f"{flag} {path_text(path)}: folder {path_text(folder)} does not exist")


def _kind(mode: int) -> str:
    kinds = ((stat.S_ISDIR, "a folder"), (stat.S_ISLNK, "a symbolic link"), (stat.S_ISFIFO, "a FIFO"),
             (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a device"), (stat.S_ISBLK, "a device"))
    return next((what for test, what in kinds if test(mode)), "not a regular file")


def identity(path: str) -> str:
    """Where a path points, for comparing outputs with inputs: the real folder joined with the name (the file
    itself may not exist yet)."""
    folder, name = os.path.split(os.path.abspath(path))
    return os.path.join(os.path.realpath(folder), name)


def same_file(output: str, given: str) -> bool:
    """Whether writing `output` would replace the file at `given` (the same name, a symlink to it, a hard link)."""
    if identity(output) in (identity(given), os.path.realpath(given)):
        return True
    try:
        return os.path.samefile(output, given)
    except OSError:
        return False


def inside(path: str, folder: str) -> bool:
    """Whether `path` is `folder` or lies inside it, links resolved."""
    path, folder = os.path.realpath(path), os.path.realpath(folder)
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


def refuse_inputs(flag: str, output: str, inputs: Iterable[Tuple[str, str]], folders: Sequence[Tuple[str, str]] = ()) -> None:
    """Refuses an `output` that is one of the `inputs` (flag, file) or lies in one of the input `folders`
    (flag, folder whose files are all inputs: a frames folder)."""
    for given_by, path in inputs:
        if same_file(output, path):
            raise FileError(f"{flag} {path_text(output)}: would overwrite the input given by {given_by}")
    for given_by, folder in folders:
        if inside(os.path.dirname(os.path.abspath(output)), folder):
            raise FileError(f"{flag} {path_text(output)}: would write into {path_text(folder)}, given by {given_by}")


class Staged:
    """Outputs being written, all or none (see the module's doc); a context manager: left without `commit` (an
    error), its temporaries and the folders made for them are removed."""

    def __init__(self) -> None:
        self._moves: List[Tuple[str, str]] = []  # (temporary, destination): files, or folders to merge
        self._folders: List[str] = []
        self._cleaned: set = set()

    def __enter__(self) -> "Staged":
        return self

    def __exit__(self, *exc) -> None:
        self.discard()

    def _temporary(self, dest: str) -> str:
        folder = os.path.dirname(os.path.abspath(dest))
        if folder not in self._cleaned:
            remove_stale(folder)
            self._cleaned.add(folder)
        tmp = sibling(dest, "tmp")
        # Listed before it exists: a signal in between finds nothing to remove, never an unlisted temporary.
        _pending.temporaries.append(tmp)
        self._moves.append((tmp, dest))
        return tmp

    def file(self, dest: str) -> str:
        """The temporary to write `dest`'s content to (dest's folder must exist; check_output_path first)."""
        return self._temporary(dest)

    def folder(self, dest: str) -> str:
        """A new temporary folder whose files become `dest`'s (a folder, made at the commit where missing)."""
        tmp = self._temporary(dest)
        try:
            os.mkdir(tmp)
        except OSError as e:
            raise _file_error(dest, "cannot write", e) from None
        return tmp

    def new_folder(self, path: str) -> None:
        """Makes a folder for outputs (its parent must exist); removed again, when empty, without a commit."""
        _pending.folders.append(path)  # listed first, as temporaries are
        try:
            os.mkdir(path)
        except OSError as e:
            _pending.folders.remove(path)
            raise _file_error(path, "cannot create the folder", e) from None
        self._folders.append(path)

    def discard(self) -> None:
        for tmp, _ in reversed(self._moves):
            _remove(tmp)
            _pending.temporaries.remove(tmp)
        for folder in reversed(self._folders):
            try:
                os.rmdir(folder)
            except OSError:
                pass
            _pending.folders.remove(folder)
        self._moves, self._folders = [], []

    def commit(self) -> None:
        """Moves every output into place, all or none; a signal meanwhile waits until the moves are done."""
        _pending.committing = True
        try:
            _move_all_into_place(self._moves)
            for tmp, _ in self._moves:
                _remove(tmp)  # what is left of a merged folder: its empty subfolders
                _pending.temporaries.remove(tmp)
            for folder in self._folders:
                _pending.folders.remove(folder)
            self._moves, self._folders = [], []
        finally:
            _pending.committing = False
            if _pending.signal is not None:
                stop(_pending.signal)


def _merged(moves: Sequence[Tuple[str, str]]) -> Tuple[List[str], List[Tuple[str, str]]]:
    """The folders to make and the (temporary file, destination) moves: a temporary folder's files go to the
    same places under its destination."""
    folders, files = [], []
    for tmp, dest in moves:
        if not os.path.isdir(tmp):
            files.append((tmp, dest))
            continue
        for root, subfolders, names in os.walk(tmp):
            target = os.path.normpath(os.path.join(dest, os.path.relpath(root, tmp)))
            if not os.path.isdir(target):
                folders.append(target)
            files.extend((os.path.join(root, n), os.path.join(target, n)) for n in sorted(names))
            subfolders.sort()
    return folders, files


def _move_all_into_place(moves: Sequence[Tuple[str, str]]) -> None:
    """Renames each temporary to its destination, all or none: an existing destination is first moved aside,
    so that when a later rename fails every output placed is removed and every file moved aside put back."""
    folders, files = _merged(moves)
    done: List[Tuple[str, str, str]] = []  # ("made", folder, ""), ("aside", dest, backup), ("placed", dest, "")
    try:
        for folder in folders:
            if not os.path.isdir(folder):
                os.mkdir(folder)
                done.append(("made", folder, ""))
        for tmp, dest in files:
            check_output_path("output", dest)
            if os.path.lexists(dest):
                backup = sibling(dest, "bak")
                os.rename(dest, backup)
                done.append(("aside", dest, backup))
            os.rename(tmp, dest)
            done.append(("placed", dest, ""))
    except (OSError, FileError) as e:
        kept = []
        for step, path, backup in reversed(done):
            try:
                if step == "made":
                    os.rmdir(path)
                elif step == "placed":
                    os.unlink(path)
                else:
                    os.rename(backup, path)
            except OSError:
                if step == "aside":
                    kept.append(f"{path_text(path)} is kept as {path_text(backup)}")
        if isinstance(e, FileError):
            raise FileError("; ".join([str(e)] + kept)) from None
        raise FileError("; ".join([str(_file_error(e.filename or "output", "cannot write", e))] + kept)) from None
    for step, _, backup in done:
        if step == "aside":
            _remove(backup)
