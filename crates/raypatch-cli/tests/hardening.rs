//! render-frame against hostile inputs, one test per class (issue 9): files outside a scene folder, inputs
//! that are not regular files, outputs that would lose or replace something, sizes and counts that would
//! overflow or exhaust memory, and finite but meaningless values. Each gives one line, exit code 2, no
//! panic, and leaves every file as it was.

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
    fails(d, &["--out", "x.gif"], &["--out x.gif", "expected a .png file, or a folder"]);
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
    for key in ["encoder_kwargs.num_att_blocks", "decoder_kwargs.num_att_blocks", "encoder_kwargs.num_conv_blocks"] {
        let (section, name) = key.split_once('.').unwrap();
        let path =
            with_config(d, &model, "counts.safetensors", |c| c[section][name] = serde_json::json!(1_000_000_000u64));
        fails(d, &["--model", "counts.safetensors"], &[key, "1000000000"]);
        std::fs::remove_file(path).unwrap();
    }

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
