"""raypatch.output, the writer of the Ray CLI: all or none, temporaries named as render-frame's, a failed move
undone, runs killed outright cleaned up after, and a signal ending the process with nothing left behind."""

import os
import signal
import subprocess
import sys
import textwrap

import pytest

import raypatch
from raypatch import output


def ours(folder):
    """Names of our temporaries and files moved aside in `folder`, recursively."""
    return sorted(name for _, dirs, files in os.walk(folder) for name in dirs + files if output.TEMP_MARK in name)


def test_all_or_nothing_and_temporaries_named_as_render_frames(tmp_path):
    keep = tmp_path / "keep.csv"
    keep.write_text("work")
    with output.Staged() as staged:
        tmp = staged.file(str(keep))
        assert os.path.basename(tmp).startswith(f".keep.csv{output.TEMP_MARK}{os.getpid()}-")
        assert tmp.endswith(".tmp")
        with open(tmp, "w") as f:
            f.write("new")
        folder = staged.folder(str(tmp_path / "views"))
        os.mkdir(os.path.join(folder, "a"))
        with open(os.path.join(folder, "a", "view_000.png"), "w") as f:
            f.write("png")
        # Left without a commit: nothing placed, nothing of ours left.
    assert keep.read_text() == "work" and not (tmp_path / "views").exists() and not ours(tmp_path)
    with output.Staged() as staged:
        with open(staged.file(str(keep)), "w") as f:
            f.write("new")
        folder = staged.folder(str(tmp_path / "views"))
        os.mkdir(os.path.join(folder, "a"))
        with open(os.path.join(folder, "a", "view_000.png"), "w") as f:
            f.write("png")
        staged.commit()
    assert keep.read_text() == "new" and (tmp_path / "views" / "a" / "view_000.png").read_text() == "png"
    assert not ours(tmp_path)


def test_a_failed_move_puts_back_what_was_replaced(tmp_path):
    (tmp_path / "views" / "a").mkdir(parents=True)
    old = tmp_path / "views" / "a" / "view_000.png"
    old.write_text("old")
    (tmp_path / "views" / "b").mkdir()
    (tmp_path / "views" / "b" / "view_001.png").mkdir()  # a folder where an output goes: its move fails
    with output.Staged() as staged:
        folder = staged.folder(str(tmp_path / "views"))
        for scene, view in (("a", "view_000.png"), ("b", "view_000.png"), ("b", "view_001.png"), ("c", "x.png")):
            os.makedirs(os.path.join(folder, scene), exist_ok=True)
            with open(os.path.join(folder, scene, view), "w") as f:
                f.write("new")
        with pytest.raises(raypatch.FileError, match="view_001.png: is a folder"):
            staged.commit()
    assert old.read_text() == "old" and not (tmp_path / "views" / "b" / "view_000.png").exists()
    assert not (tmp_path / "views" / "c").exists() and not ours(tmp_path)


def test_runs_killed_outright_are_cleaned_up_after(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True).stdout.strip()
    (tmp_path / f".results.csv.raypatch-{dead}-0.tmp").write_text("partial")
    (tmp_path / f".views.raypatch-{dead}-1.tmp" / "a").mkdir(parents=True)
    (tmp_path / f".kept.csv.raypatch-{dead}-2.bak").write_text("the user's")  # moved aside, never put back
    (tmp_path / f".other.csv.raypatch-{os.getpid()}-3.tmp").write_text("a live run's")
    with output.Staged() as staged:
        staged.file(str(tmp_path / "results.csv"))
    assert (tmp_path / "kept.csv").read_text() == "the user's"
    assert ours(tmp_path) == [f".other.csv.raypatch-{os.getpid()}-3.tmp"]


def test_long_names_get_temporaries_that_fit():
    name = "v" * 250 + ".png"
    tmp = output.sibling(os.path.join("out", name), "tmp")
    assert len(os.fsencode(os.path.basename(tmp))) <= output.MAX_NAME_BYTES and tmp.endswith(".tmp")


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_removes_the_temporaries_and_exits_128_plus_it(tmp_path, signum):
    script = textwrap.dedent(f"""
        import os, sys, time
        from raypatch import output
        output.stop_on_signals("test")
        staged = output.Staged()
        staged.new_folder({str(tmp_path / "new")!r})
        open(staged.file({str(tmp_path / "new" / "a.csv")!r}), "w").close()
        os.mkdir(os.path.join(staged.folder({str(tmp_path / "views")!r}), "scene"))
        print("ready", flush=True)
        time.sleep(60)
    """)
    run = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert run.stdout.readline().strip() == "ready", run.stderr.read()
    run.send_signal(signum)
    assert run.wait(timeout=30) == 128 + signum
    assert "stopped by" in run.stderr.read()
    assert os.listdir(tmp_path) == []
