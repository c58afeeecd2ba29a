//! render-frame against hostile inputs, one test per class (issues 9 and 27): files outside a scene folder,
//! inputs that are not regular files, outputs that would lose or replace something (also when a rename fails
//! half-way), sizes and counts that would overflow or exhaust memory (also files far larger than what they
//! hold), finite but meaningless values (also degenerate cameras), and messages about output names. Each gives
//! one line, exit code 2, no panic, and leaves every file as it was.

mod common;

use std::path::Path;

use common::*;
use raypatch::Image;
use tempfile::TempDir;

fn json_edit(folder: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let path = folder.join("transforms.json");
    let mut json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    edit(&mut json);
    std::fs::write(path, json.to_string()).unwrap();
}

#[test]
fn frame_files_must_stay_inside_the_scene_folder() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let folder = frames_folder(d, 3);
    let scene = folder.display().to_string();
    // A real PNG outside the folder, by `..`, by an absolute path and by a symlink.
    Image::new(32, 24, vec![0.5; 32 * 24 * 3]).unwrap().save_png(d.join("outside.png")).unwrap();
    let absolute = d.join("outside.png").display().to_string();
    for name in ["../outside.png", absolute.as_str(), "../../../../etc/passwd"] {
        json_edit(&folder, |j| j["frames"][1]["file_path"] = serde_json::json!(name));
        fails(d, &["--scene", &scene], &["frame 1", "not a relative path inside the scene folder"]);
    }
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(d.join("outside.png"), folder.join("link.png")).unwrap();
        std::os::unix::fs::symlink(d.join("absent.png"), folder.join("dangling.png")).unwrap();
        for name in ["link.png", "dangling.png"] {
            json_edit(&folder, |j| j["frames"][1]["file_path"] = serde_json::json!(name));
            // The same words whether or not the outside file exists.
            fails(d, &["--scene", &scene], &["frame 1", "does not name a regular file inside the scene folder"]);
        }
    }
}

#[cfg(unix)]
#[test]
fn inputs_that_are_not_regular_files_are_refused_without_reading() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let fifo = d.join("fifo.safetensors");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let fifo = fifo.display().to_string();
    fails(d, &["--model", &fifo], &["fifo.safetensors", "a FIFO, not a regular file"]);
    fails(d, &["--scene", &fifo], &["fifo.safetensors", "a FIFO, not a regular file"]);
    fails(d, &["--pose", &fifo], &["fifo.safetensors", "a FIFO, not a regular file"]);
    fails(d, &["--model", "/dev/zero"], &["/dev/zero", "a device, not a regular file"]);
    let folder = frames_folder(d, 3);
    std::fs::remove_file(folder.join("r_1.png")).unwrap();
    let c = std::ffi::CString::new(folder.join("r_1.png").to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    fails(d, &["--scene", folder.to_str().unwrap()], &["frame 1", "does not name a regular file"]);
}

#[test]
fn a_failed_run_leaves_every_file_as_it_was() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    std::fs::write(d.join("keep.png"), b"work").unwrap();
    std::fs::create_dir(d.join("raw.safetensors")).unwrap();
    fails(d, &["--out", "keep.png", "--out-raw", "raw.safetensors"], &["raw.safetensors", "a folder"]);
    assert_eq!(std::fs::read(d.join("keep.png")).unwrap(), b"work");

    let model = golden("rpsrt_k4", "model.safetensors");
    std::fs::copy(&model, d.join("model.safetensors")).unwrap();
    fails(
        d,
        &[
            "--model",
            "model.safetensors",
            "--scene",
            &golden("rpsrt_k4", "scene.safetensors"),
            "--out-raw",
            "./model.safetensors",
        ],
        &["--out-raw", "would overwrite the input given by --model"],
    );
    fails(d, &["--out-raw", "x.png"], &["--out-raw x.png", "ending in .safetensors"]);
    fails(d, &["--out", "x.jpg"], &["--out x.jpg", "expected a .png file, a video (.mp4 or .gif), or a folder"]);
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(d.join("keep.png"), d.join("link.png")).unwrap();
        fails(d, &["--out", "link.png"], &["link.png", "a symbolic link; only regular files are replaced"]);
        assert_eq!(std::fs::read(d.join("keep.png")).unwrap(), b"work");
    }
    // Two renders into the same folder, the second killed half-way, is simulated by a stale temporary of a
    // process that no longer exists: the next run removes it.
    std::fs::remove_dir(d.join("raw.safetensors")).unwrap();
    std::fs::write(d.join(".render.png.raypatch-4294967294-0.tmp"), b"stale").unwrap();
    let r = run(d, &[]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    if Path::new("/proc/self").exists() {
        assert!(!d.join(".render.png.raypatch-4294967294-0.tmp").exists());
    }
}

/// A PNG of 1x1 pixel whose header declares `width` x `height` (the IHDR chunk patched, CRC recomputed).
fn png_declaring(path: &Path, width: u32, height: u32) {
    let mut bytes = Image::new(1, 1, vec![0.5; 3]).unwrap().encode_png().unwrap();
    bytes[16..20].copy_from_slice(&width.to_be_bytes());
    bytes[20..24].copy_from_slice(&height.to_be_bytes());
    let crc = crc32(&bytes[12..29]);
    bytes[29..33].copy_from_slice(&crc.to_be_bytes());
    std::fs::write(path, bytes).unwrap();
}

fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

#[test]
fn sizes_and_counts_are_bounded_before_anything_is_allocated() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let folder = frames_folder(d, 3);
    let scene = folder.display().to_string();
    for (w, h) in [(22000, 22000), (8192, 8192), (100000, 1)] {
        png_declaring(&folder.join("r_1.png"), w, h);
        fails(
            d,
            &["--scene", &scene],
            &["r_1.png", &format!("{w}x{h} (width x height) is larger than raypatch accepts")],
        );
    }
    // A size that is accepted but too large for the GPU's buffers: a clear error from the plan.
    let big = image::GrayImage::new(2048, 2048);
    for i in 0..3 {
        big.save(folder.join(format!("r_{i}.png"))).unwrap();
    }
    json_edit(&folder, |j| j["camera_angle_x"] = serde_json::json!(0.8));
    fails(d, &["--scene", &scene], &["too many input views, or too large", "more than the"]);

    let model = golden("rpsrt_k4", "model.safetensors");
    let osrt = golden("osrt", "model.safetensors");
    for (model, key) in [
        (&model, "encoder_kwargs.num_att_blocks"),
        (&model, "decoder_kwargs.num_att_blocks"),
        (&model, "encoder_kwargs.num_conv_blocks"),
        (&model, "rp_kwargs.h_in"),
        (&osrt, "encoder_kwargs.slot_iters"),
        (&osrt, "decoder_kwargs.render_mlp_hidden"),
    ] {
        let (section, name) = key.split_once('.').unwrap();
        let path =
            with_config(d, model, "counts.safetensors", |c| c[section][name] = serde_json::json!(1_000_000_000u64));
        fails(d, &["--model", "counts.safetensors"], &[key, "1000000000"]);
        std::fs::remove_file(path).unwrap();
    }

    // A scene file with more target views than any scene may have (each would be a render).
    let many = edited(d, &golden("rpsrt_k4", "scene.safetensors"), "many.safetensors", |t| {
        let positions: Vec<u8> = (0..10_001 * 3).flat_map(|i| (i as f32).to_le_bytes()).collect();
        t.insert("target_camera_pos".into(), (safetensors::Dtype::F32, vec![10_001, 3], positions));
    });
    fails(d, &["--scene", &many], &["many.safetensors", "target_camera_pos", "10001 views", "at most 10000"]);
    fails(d, &["--region", "18446744073709551615,0,1,1"], &["region", "not inside"]);
    fails(d, &["--region", "0,0,18446744073709551615,18446744073709551615"], &["region", "not inside"]);
    fails(d, &["--repeat", "18446744073709551615"], &["--repeat", "from 0 to 100000"]);
    fails(d, &["--orbit-frames", "18446744073709551615"], &["--orbit-frames", "from 0 to 100000"]);
    fails(d, &["--max-buffer-mib", "17592186044416"], &["--max-buffer-mib", "17592186044416"]);
    fails(d, &["--max-buffer-mib", "1"], &["--max-buffer-mib 1", "more than the 1048576 bytes"]);
    std::fs::write(
        d.join("wide.json"),
        r#"{"w": 1e9, "transform_matrix": [[1,0,0,0],[0,0,-1,-6],[0,1,0,1],[0,0,0,1]]}"#,
    )
    .unwrap();
    fails(d, &["--pose", "wide.json"], &["wide.json", "`w` is 1000000000"]);
}

#[test]
fn finite_but_meaningless_inputs_are_refused() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let scene = golden("rpsrt_k4", "scene.safetensors");
    let model = golden("rpsrt_k4", "model.safetensors");
    let scaled = |name: &str, key: &str, factor: f32| {
        edited(d, &scene, name, |t| {
            let bytes = &mut t.get_mut(key).unwrap().2;
            for chunk in bytes.chunks_exact_mut(4) {
                let v = f32::from_le_bytes(chunk.try_into().unwrap()) * factor;
                chunk.copy_from_slice(&v.to_le_bytes());
            }
        })
    };
    for (name, key, factor) in
        [("big-rays.safetensors", "target_rays", 1e30), ("small-rays.safetensors", "input_rays", 1e-5)]
    {
        let f = scaled(name, key, factor);
        fails(d, &["--model", &model, "--scene", &f], &["unit ray directions"]);
    }
    let f = scaled("far.safetensors", "input_camera_pos", 1e30);
    fails(d, &["--model", &model, "--scene", &f], &["input view 0", "cannot encode this camera"]);
    let bundled = root().join("assets/scenes/scene-2000000.safetensors").display().to_string();
    let f = edited(d, &bundled, "bytes.safetensors", |t| set_f32(t, "target_images", 7, 255.0));
    fails(d, &["--scene", &f, "--metrics"], &["target_images", "element 7 is 255, expected RGB values in [0, 1]"]);
    std::fs::write(d.join("far.json"), r#"{"transform_matrix": [[1,0,0,1e308],[0,0,-1,-6],[0,1,0,1],[0,0,0,1]]}"#)
        .unwrap();
    fails(d, &["--pose", "far.json"], &["cannot encode this camera"]);

    with_config(d, &model, "octave.safetensors", |c| c["encoder_kwargs"]["pos_start_octave"] = serde_json::json!(1000));
    fails(
        d,
        &["--model", "octave.safetensors"],
        &["encoder_kwargs.pos_start_octave", "outside float32's normal range"],
    );

    let f = edited(d, &model, "huge.safetensors", |t| {
        let w = &mut t.get_mut("encoder.per_patch_linear.weight").unwrap().2;
        for chunk in w.chunks_exact_mut(4) {
            chunk.copy_from_slice(&3e38f32.to_le_bytes());
        }
    });
    fails(d, &["--model", &f, "--scene", &scene], &["encode", "first become NaN or infinity in op `encoder."]);
}

#[test]
fn messages_say_what_a_path_should_have_been() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let model = golden("rpsrt_k4", "model.safetensors");
    fails(d, &["--scene", &model], &["input_images", "this is a model file", "scene .safetensors file"]);
    let scene = golden("rpsrt_k4", "scene.safetensors");
    fails(d, &["--model", &scene], &["this is a scene file", "expected a model .safetensors file"]);
    Image::new(2, 2, vec![0.5; 12]).unwrap().save_png(d.join("x.png")).unwrap();
    fails(d, &["--scene", "x.png"], &["x.png", "looks like a PNG image", "or a folder with transforms.json"]);
    // The bundled model and scene are in the binary: it renders from any folder.
    let r = run(d, &["--list-adapters"]);
    assert_eq!(r.code, 0);
    assert!(r.stdout.lines().next().is_some_and(|l| l.ends_with("[default]")), "{}", r.stdout);
}

fn bytemuck_floats(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// Runs render-frame in `dir` and returns its exit code, its stderr and its peak resident memory in bytes
/// (its own, from wait4: not that of other tests' runs).
#[cfg(unix)]
#[allow(clippy::zombie_processes)] // reaped by wait4, which std's Child does not know of
fn run_with_peak(dir: &Path, args: &[&str]) -> (i32, String, u64) {
    use std::io::Read;
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_render-frame"))
        .args(args)
        .current_dir(dir)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut stderr = String::new();
    child.stderr.take().unwrap().read_to_string(&mut stderr).unwrap();
    let (mut status, mut usage): (libc::c_int, libc::rusage) = (0, unsafe { std::mem::zeroed() });
    assert_eq!(unsafe { libc::wait4(child.id() as libc::pid_t, &mut status, 0, &mut usage) }, child.id() as i32);
    (libc::WEXITSTATUS(status), stderr, usage.ru_maxrss as u64 * 1024)
}

/// A copy of a safetensors file with one more F32 tensor of `len` values, stored sparse (its bytes are never
/// written, the file is only extended): a valid file far larger than what it holds.
fn with_sparse_tensor(dir: &Path, source: &str, name: &str, key: &str, shape: &[u64]) -> String {
    let bytes = std::fs::read(source).unwrap();
    let header_len = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let mut header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + header_len]).unwrap();
    let data = &bytes[8 + header_len..];
    let extra: u64 = 4 * shape.iter().product::<u64>();
    let end = data.len() as u64 + extra;
    header[key] = serde_json::json!({"dtype": "F32", "shape": shape, "data_offsets": [data.len(), end]});
    let mut text = header.to_string();
    text.push_str(&" ".repeat((8 - text.len() % 8) % 8));
    let path = dir.join(name);
    let mut out = (text.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(text.as_bytes());
    out.extend_from_slice(data);
    std::fs::write(&path, &out).unwrap();
    std::fs::OpenOptions::new().write(true).open(&path).unwrap().set_len(out.len() as u64 + extra).unwrap();
    path.display().to_string()
}

#[cfg(unix)]
#[test]
fn files_larger_than_what_they_hold_are_never_read_whole() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let model = golden("rpsrt_k4", "model.safetensors");
    let scene = golden("rpsrt_k4", "scene.safetensors");
    // 10 GiB in a tensor no model has, in a weight of the wrong shape, and in a scene's images.
    let junk = with_sparse_tensor(d, &model, "junk.safetensors", "junk", &[10 << 28]);
    fails(d, &["--model", &junk, "--scene", &scene], &["junk.safetensors", "unexpected tensor `junk`"]);
    let key = "decoder_rp.conv_decoder.conv_0.bias";
    let mut wrong = read_f32_tensors(&model);
    wrong.0.remove(key);
    write_tensors(&d.join("cut.safetensors"), &wrong.0, &wrong.1);
    let huge =
        with_sparse_tensor(d, &d.join("cut.safetensors").display().to_string(), "w.safetensors", key, &[10 << 28]);
    std::fs::remove_file(d.join("cut.safetensors")).unwrap();
    fails(d, &["--model", &huge, "--scene", &scene], &["w.safetensors", key, "[2684354560]"]);
    let mut images = read_f32_tensors(&scene);
    images.0.remove("input_images");
    write_tensors(&d.join("cut.safetensors"), &images.0, &images.1);
    let big = with_sparse_tensor(
        d,
        &d.join("cut.safetensors").display().to_string(),
        "s.safetensors",
        "input_images",
        &[1, 16384, 65536, 3],
    );
    std::fs::remove_file(d.join("cut.safetensors")).unwrap();
    fails(d, &["--model", &model, "--scene", &big], &["s.safetensors", "input_images", "bytes, more than"]);
    for args in [
        ["--model", &junk, "--scene", &scene],
        ["--model", &huge, "--scene", &scene],
        ["--model", &model, "--scene", &big],
    ] {
        let (code, stderr, peak) = run_with_peak(d, &args);
        assert_eq!(code, 2, "{args:?}: {stderr}");
        assert!(peak < 1 << 30, "{args:?}: render-frame peaked at {peak} bytes");
    }
}

/// render-frame with the pipeline cache in `cache`, killed after a minute (a FIFO that blocked would hang it).
#[cfg(unix)]
fn run_with_cache(dir: &Path, cache: &Path) -> Run {
    use std::process::Stdio;
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_render-frame"))
        .current_dir(dir)
        .env("RAYPATCH_CACHE_DIR", cache)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed().as_secs() > 120 {
            child.kill().unwrap();
            panic!("render-frame hung with the pipeline cache in {}", cache.display());
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let out = child.wait_with_output().unwrap();
    Run {
        code: out.status.code().unwrap_or(-1),
        stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
    }
}

#[cfg(unix)]
#[test]
fn the_pipeline_cache_is_read_like_every_other_input() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let cache = d.join("cache");
    let first = run_with_cache(d, &cache);
    assert_eq!(first.code, 0, "{}", first.stderr);
    let Some(entry) = std::fs::read_dir(&cache).ok().and_then(|mut e| e.next()) else {
        eprintln!("this adapter keeps no pipeline cache: nothing to check");
        return;
    };
    let file = entry.unwrap().path();
    std::fs::remove_file(&file).unwrap();
    let c = std::ffi::CString::new(file.to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let r = run_with_cache(d, &cache);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert!(r.stderr.contains("a FIFO, not a regular file: not used"), "{}", r.stderr);
    std::fs::remove_file(&file).unwrap();
    std::os::unix::fs::symlink("/dev/zero", &file).unwrap();
    let r = run_with_cache(d, &cache);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert!(r.stderr.contains("a device, not a regular file: not used"), "{}", r.stderr);
    assert!(std::fs::symlink_metadata(&file).unwrap().file_type().is_symlink(), "the link was replaced");
}

#[test]
fn degenerate_cameras_are_refused_naming_the_file_and_frame() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let folder = frames_folder(d, 3);
    let scene = folder.display().to_string();
    // Per-frame intrinsics override the folder's camera_angle_x.
    for (keys, named, reason) in [
        (serde_json::json!({"fl_x": 1e-200}), "fx=1e-200", "from the optical axis"),
        (serde_json::json!({"fl_x": 1e-310}), "fx=1e-310", "from the optical axis"),
        (serde_json::json!({"fl_x": 1e200}), "fx=1e200", "the image spans"),
        (serde_json::json!({"fl_x": 35.0, "cx": 1e300}), "cx=1e300", "from the optical axis"),
        (serde_json::json!({"fl_x": 35.0, "cy": -1e9}), "cy=-1000000000.0", "from the optical axis"),
        (serde_json::json!({"camera_angle_x": std::f64::consts::PI}), "camera_angle_x", "between 0 and π"),
        (serde_json::json!({"camera_angle_x": 0.0}), "camera_angle_x", "between 0 and π"),
    ] {
        let original = std::fs::read(folder.join("transforms.json")).unwrap();
        json_edit(&folder, |j| {
            for (key, value) in keys.as_object().unwrap() {
                j["frames"][2][key] = value.clone();
            }
        });
        fails(d, &["--scene", &scene], &["transforms.json", "frame 2", named, reason]);
        std::fs::write(folder.join("transforms.json"), original).unwrap();
    }
    // Rays given as such (a scene file) that all point the same way.
    let scene = golden("rpsrt_k4", "scene.safetensors");
    let model = golden("rpsrt_k4", "model.safetensors");
    let same = edited(d, &scene, "same.safetensors", |t| {
        for ray in t.get_mut("target_rays").unwrap().2.chunks_exact_mut(12) {
            ray.copy_from_slice(bytemuck_floats(&[0.0, 0.0, 1.0]).as_slice());
        }
    });
    fails(d, &["--model", &model, "--scene", &same], &["same.safetensors", "target view 0", "degenerate"]);
    let pose = r#"{"transform_matrix": [[1,0,0,0],[0,0,-1,-6],[0,1,0,1],[0,0,0,1]], "fl_x": 1e-200}"#;
    std::fs::write(d.join("pose.json"), pose).unwrap();
    fails(d, &["--pose", "pose.json"], &["pose.json", "from the optical axis"]);
}

#[test]
fn output_names_get_the_message_they_need() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    fails(d, &["--out", "/dev/null"], &["--out /dev/null", "is a device", "expected a .png file, or a folder"]);
    std::fs::write(d.join("notes"), b"mine").unwrap();
    fails(d, &["--out", "notes"], &["--out notes", "an existing file without the .png extension"]);
    assert_eq!(std::fs::read(d.join("notes")).unwrap(), b"mine");
    // The longest names a file system takes are written (their temporaries' names are shortened).
    for len in [232, 255] {
        let name = format!("{}.png", "n".repeat(len - 4));
        let r = run(d, &["--out", &name]);
        assert_eq!(r.code, 0, "{len}: {}", r.stderr);
        assert!(png_size(&d.join(&name)).0 > 0);
    }
    fails(d, &["--out", &format!("{}.png", "n".repeat(252))], &["256 bytes, more than the 255"]);
}

/// A later output's rename fails (a sticky shared folder where that file belongs to another user): the run
/// exits 2 and the earlier output's file is as it was. Needs root, to run render-frame as another user.
#[cfg(unix)]
#[test]
fn a_rename_that_fails_half_way_loses_nothing() {
    use std::os::unix::fs::{chown, PermissionsExt};
    if unsafe { libc::geteuid() } != 0 || !Path::new("/usr/bin/setpriv").exists() {
        eprintln!("skipped: needs root and setpriv to run render-frame as another user");
        return;
    }
    let dir = TempDir::new().unwrap();
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
    let shared = dir.path().join("shared");
    std::fs::create_dir(&shared).unwrap();
    std::fs::set_permissions(&shared, std::fs::Permissions::from_mode(0o1777)).unwrap();
    let (mine, theirs) = (shared.join("mine.png"), shared.join("theirs.safetensors"));
    std::fs::write(&mine, b"work").unwrap();
    chown(&mine, Some(65534), Some(65534)).unwrap();
    std::fs::write(&theirs, b"theirs").unwrap();
    std::fs::set_permissions(&theirs, std::fs::Permissions::from_mode(0o666)).unwrap();
    let out = std::process::Command::new("/usr/bin/setpriv")
        .args(["--reuid=65534", "--regid=65534", "--clear-groups", env!("CARGO_BIN_EXE_render-frame")])
        .args(["--out", "mine.png", "--out-raw", "theirs.safetensors"])
        .current_dir(&shared)
        .env("RAYPATCH_CACHE_DIR", "off")
        .env("MESA_SHADER_CACHE_DISABLE", "true")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("theirs.safetensors") && stderr.lines().count() == 1, "{stderr}");
    assert_eq!(std::fs::read(&mine).unwrap(), b"work");
    assert_eq!(std::fs::read(&theirs).unwrap(), b"theirs");
    assert_eq!(files(&shared), ["mine.png", "theirs.safetensors"]);
}

/// A huge value (a camera matrix of a million numbers, a flag of 100 kB) is quoted as a bounded excerpt: the
/// message still names the file or flag and what was expected, in at most a few kB.
#[test]
fn messages_quote_bounded_excerpts_of_huge_inputs() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let huge: Vec<f64> = (0..1_000_000).map(|i| i as f64 + 0.25).collect();
    let path = serde_json::json!({
        "render_width": 80, "render_height": 60, "fps": 24, "camera_type": "perspective",
        "camera_path": [{"camera_to_world": huge, "fov": 40}],
    });
    std::fs::write(d.join("path.json"), path.to_string()).unwrap();
    let long = "9,".repeat(50_000);
    let views = format!("{}x", "0,".repeat(50_000));
    let cases: [(&[&str], &[&str]); 4] = [
        (&["--camera-path", "path.json", "--out", "x.mp4"], &["path.json", "camera_to_world", "characters)"]),
        (&["--region", &long], &["--region", "X,Y,W,H"]),
        (&["--view", &views], &["--view", "\"x\" is not an index", "characters)"]),
        (&["--motion", "orbit", "--centre", &long], &["--centre", "X,Y,Z"]),
    ];
    for (args, expected) in cases {
        fails(d, args, expected);
        let r = run(d, args);
        assert!(r.stderr.len() < 4000, "{:.80}: {} bytes of stderr", args.join(" "), r.stderr.len());
    }
}

/// render-frame with HOME `home` (XDG, raypatch's and Mesa's cache variables unset), optionally as another user
/// by `setpriv` (`as_user`: its arguments), rendering into `out`, which cannot be written.
fn render_homeless(dir: &Path, home: &Path, out: &Path, as_user: &[&str]) -> std::process::Output {
    let bin = env!("CARGO_BIN_EXE_render-frame");
    let mut command = if as_user.is_empty() {
        std::process::Command::new(bin)
    } else {
        let mut c = std::process::Command::new("setpriv");
        c.args(as_user).arg(bin);
        c
    };
    command.args(["--model", &golden("rpsrt_k4", "model.safetensors")]);
    command.args(["--scene", &golden("rpsrt_k4", "scene.safetensors"), "--out"]).arg(out);
    for var in ["XDG_CACHE_HOME", "RAYPATCH_CACHE_DIR", "MESA_SHADER_CACHE_DIR", "MESA_SHADER_CACHE_DISABLE"] {
        command.env_remove(var);
    }
    command.env_remove("MESA_GLSL_CACHE_DIR").env_remove("MESA_GLSL_CACHE_DISABLE");
    command.env("HOME", home).current_dir(dir).output().unwrap()
}

#[test]
fn a_home_that_cannot_be_written_adds_no_lines() {
    // Issue 50: Mesa said four times that it could not make its shader cache under HOME, and raypatch once that
    // it could not read its pipeline cache there: a one-line refusal became six lines. Mesa's cache now goes
    // to raypatch's cache folder or is off (said by --timings), and raypatch's goes unused, unsaid.
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let file = d.join("a-file");
    std::fs::write(&file, b"not a folder").unwrap();
    let out = file.join("frames/out.png");
    let r = render_homeless(d, &file.join("home"), &out, &[]);
    let stderr = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "not one line: {stderr}");
    assert!(stderr.contains("--out") && !stderr.contains("cache"), "{stderr}");
    // A run that succeeds says where the caches went under --timings, and nothing about them on stderr.
    let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_render-frame"));
    command.args(["--timings", "--out", "ok.png"]).env("HOME", file.join("home")).current_dir(d);
    for var in ["XDG_CACHE_HOME", "RAYPATCH_CACHE_DIR", "MESA_SHADER_CACHE_DIR", "MESA_SHADER_CACHE_DISABLE"] {
        command.env_remove(var);
    }
    let ok = command.output().unwrap();
    let (stdout, stderr) = (String::from_utf8_lossy(&ok.stdout), String::from_utf8_lossy(&ok.stderr));
    assert!(ok.status.success(), "{stderr}");
    assert!(stdout.contains("\nMesa's shader cache: off (") && stdout.contains("; no pipeline cache: "), "{stdout}");
    assert!(!stderr.contains("cache"), "{stderr}");
    std::fs::remove_file(d.join("ok.png")).unwrap();
    // As `nobody`, whose home does not exist, rendering into a folder it cannot write (root can give up its
    // rights with setpriv; elsewhere this part is skipped, saying why).
    #[cfg(unix)]
    {
        let nobody = ["--reuid=65534", "--regid=65534", "--clear-groups"];
        let root = unsafe { libc::geteuid() } == 0;
        let can = root
            && std::process::Command::new("setpriv")
                .args(nobody)
                .arg(env!("CARGO_BIN_EXE_render-frame"))
                .arg("--version")
                .output()
                .is_ok_and(|o| o.status.success());
        if !can {
            eprintln!("skipped the nobody run: needs root, setpriv, and render-frame and the golden files readable by nobody");
            return;
        }
        let private = d.join("private");
        std::fs::create_dir(&private).unwrap();
        std::fs::set_permissions(d, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
        std::fs::set_permissions(&private, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
        let r = render_homeless(d, Path::new("/nonexistent"), &private.join("out.png"), &nobody);
        let stderr = String::from_utf8_lossy(&r.stderr);
        if stderr.contains("Permission denied") && stderr.contains("golden") {
            eprintln!("skipped the nobody run: the golden files are not readable by nobody: {stderr}");
            return;
        }
        assert_eq!(r.status.code(), Some(2), "{stderr}");
        assert_eq!(stderr.lines().count(), 1, "not one line as nobody: {stderr}");
        assert!(!stderr.contains("cache"), "{stderr}");
    }
}
