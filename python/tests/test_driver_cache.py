"""Issue 50: where HOME cannot be written (a service account, a read-only container), a failing render says one
line, not Mesa's four shader-cache warnings and raypatch's pipeline-cache warning before it: the package points
Mesa's cache at raypatch's cache folder, or turns it off, when imported."""

import os
import subprocess
import sys

SCRIPT = """
import sys
import raypatch
try:
    model = raypatch.bundled("rpsrt_k4")
    model.encode_scene(raypatch.bundled_scene()).render_view(0).save(sys.argv[1])
except raypatch.Error as error:
    print(error, file=sys.stderr)
    sys.exit(2)
print(raypatch.DRIVER_CACHE_NOTE)
"""


def unwritable_home(tmp_path):
    """A file standing where HOME's folders would be, and an environment whose HOME lies under it, with no cache
    settings of the user's or Mesa's."""
    not_a_folder = tmp_path / "a-file"
    not_a_folder.write_text("not a folder")
    env = {k: v for k, v in os.environ.items()
           if k not in ("XDG_CACHE_HOME", "RAYPATCH_CACHE_DIR") and not k.startswith("MESA_")}
    env["HOME"] = str(not_a_folder / "home")
    return not_a_folder, env


def test_a_failing_render_with_an_unwritable_home_says_one_line(tmp_path):
    not_a_folder, env = unwritable_home(tmp_path)
    result = subprocess.run([sys.executable, "-c", SCRIPT, str(not_a_folder / "frames" / "out.png")],
                            capture_output=True, text=True, env=env, timeout=600)
    assert result.returncode == 2, (result.stdout, result.stderr)
    assert len(result.stderr.splitlines()) == 1, result.stderr
    assert "cache" not in result.stderr, result.stderr


def test_a_users_mesa_cache_is_kept_and_an_unwritable_home_is_noted(tmp_path):
    not_a_folder, env = unwritable_home(tmp_path)
    code = "import os, raypatch; print(raypatch.DRIVER_CACHE_NOTE); print(os.environ.get('MESA_SHADER_CACHE_DISABLE'))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True).stdout
    assert out.splitlines() == [out.splitlines()[0], "true"] and "Mesa's shader cache: off" in out, out
    env["RAYPATCH_CACHE_DIR"] = str(tmp_path / "cache")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True).stdout
    assert str(tmp_path / "cache" / "mesa_shader_cache") in out and out.splitlines()[1] == "None", out
    env["MESA_SHADER_CACHE_DIR"] = str(tmp_path / "mine")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True).stdout
    assert out.splitlines() == ["None", "None"], out
