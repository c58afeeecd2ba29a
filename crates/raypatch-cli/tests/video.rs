//! Videos and sequences: a nerfstudio camera path to an MP4 that ffprobe reads (frame count, size, duration)
//! whose first frame is the PNG render of the same pose, and to a GIF; the MP4 encodings (--mp4); every motion
//! preset and interpolation; --size, --fov and --panels; bad flags as one-line errors with nothing written.
//!
//! ffprobe and ffmpeg read the MP4s: .ci/run installs them (`apt-get install ffmpeg`), and these tests fail,
//! saying so, where they are missing.

mod common;

use std::path::Path;
use std::process::Command;

use common::*;
use glam::{DMat4, DVec3};
use raypatch::Camera;
use serde_json::{json, Value};
use tempfile::TempDir;

/// Camera-to-world poses with OpenGL axes of MSN-style cameras around the bundled scene.
fn opengl_poses(n: usize) -> Vec<DMat4> {
    (0..n)
        .map(|i| {
            let angle = i as f64 * 0.3;
            let eye = DVec3::new(9.0 * angle.cos(), 9.0 * angle.sin(), 5.0);
            let (_, cv) = Camera::msn(eye, 80, 60).unwrap().as_pinhole().unwrap();
            DMat4::from_cols(cv.x_axis, -cv.y_axis, -cv.z_axis, cv.w_axis)
        })
        .collect()
}

/// A camera_path.json as nerfstudio's viewer exports it.
fn nerfstudio_path(poses: &[DMat4], (width, height): (usize, usize), fps: f64, fov: f64) -> Value {
    let cameras: Vec<Value> = (poses.iter())
        .map(|p| json!({"camera_to_world": p.transpose().to_cols_array().to_vec(), "fov": fov, "aspect": width as f64 / height as f64}))
        .collect();
    json!({"camera_type": "perspective", "render_width": width, "render_height": height, "fps": fps,
           "seconds": poses.len() as f64 / fps, "smoothness_value": 0.5, "is_cycle": false, "crop": null,
           "keyframes": [], "camera_path": cameras})
}

/// A `--pose` file of the same camera: OpenGL axes, the focal length the fov gives.
fn pose_file(pose: &DMat4, (width, height): (usize, usize), fov: f64) -> Value {
    let focal = (height as f64 / 2.0) / (fov.to_radians() / 2.0).tan();
    let rows: Vec<Vec<f64>> = (0..4).map(|r| pose.row(r).to_array().to_vec()).collect();
    json!({"fl_x": focal, "fl_y": focal, "w": width, "h": height, "transform_matrix": rows})
}

fn tool(name: &str, args: &[&str]) -> std::process::Output {
    let out = Command::new(name).args(args).output().unwrap_or_else(|e| {
        panic!("{name} is needed to read the MP4s ({e}): apt-get install ffmpeg (.ci/run installs it)")
    });
    assert!(out.status.success(), "{name} {args:?}: {}", String::from_utf8_lossy(&out.stderr));
    out
}

/// What ffprobe reads of a video's first stream.
#[derive(Debug)]
struct Probe {
    frames: usize,
    width: usize,
    height: usize,
    seconds: f64,
    codec: String,
    /// The H.264 profile: "Constrained Baseline" (OpenH264, `--mp4 compact`) or "High 4:4:4 Predictive"
    /// (`--mp4 lossless`).
    profile: String,
    pix_fmt: String,
}

fn probe(path: &Path) -> Probe {
    let out = tool(
        "ffprobe",
        &[
            "-v",
            "error",
            "-count_frames",
            "-select_streams",
            "v:0",
            "-show_entries",
            "stream=codec_name,profile,pix_fmt,width,height,nb_read_frames,duration",
            "-of",
            "json",
            path.to_str().unwrap(),
        ],
    );
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    let s = &v["streams"][0];
    let number = |key: &str| s[key].as_str().map_or_else(|| s[key].as_f64().unwrap(), |t| t.parse().unwrap());
    let text = |key: &str| s[key].as_str().unwrap().to_string();
    Probe {
        frames: number("nb_read_frames") as usize,
        width: number("width") as usize,
        height: number("height") as usize,
        seconds: number("duration"),
        codec: text("codec_name"),
        profile: text("profile"),
        pix_fmt: text("pix_fmt"),
    }
}

const LOSSLESS: &str = "High 4:4:4 Predictive";
const COMPACT: &str = "Constrained Baseline";

/// Every frame of a video, decoded by ffmpeg to RGB (as `ffmpeg -i video.mp4 frame.png` converts it).
fn decoded_frames(video: &Path) -> Vec<image::RgbImage> {
    let Probe { width, height, .. } = probe(video);
    let out =
        tool("ffmpeg", &["-v", "error", "-i", video.to_str().unwrap(), "-f", "rawvideo", "-pix_fmt", "rgb24", "-"]);
    let frame = |bytes: &[u8]| image::RgbImage::from_raw(width as u32, height as u32, bytes.to_vec()).unwrap();
    out.stdout.chunks(3 * width * height).map(frame).collect()
}

fn png(path: &Path) -> image::RgbImage {
    image::open(path).unwrap().to_rgb8()
}

fn psnr(a: &image::RgbImage, b: &image::RgbImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let mse = a.as_raw().iter().zip(b.as_raw()).map(|(&x, &y)| (x as f64 - y as f64).powi(2)).sum::<f64>()
        / a.as_raw().len() as f64;
    10.0 * (255.0f64 * 255.0 / mse).log10()
}

/// The highest PSNR against `image` that any 4:2:0 video can reach when its decoder repeats each chroma sample
/// over its 2x2 pixels, as ffmpeg's conversion to RGB does: every pixel may take its own grey level (luma), but
/// the four pixels of a block share their colour difference, so at best each keeps the block's mean in the two
/// directions across grey (clamping to 0-255 and whole levels left out).
fn chroma_420_ceiling(image: &image::RgbImage) -> f64 {
    let (width, height) = image.dimensions();
    let mut squares = 0.0;
    for (bx, by) in (0..height / 2).flat_map(|y| (0..width / 2).map(move |x| (2 * x, 2 * y))) {
        let block = [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(dx, dy)| image.get_pixel(bx + dx, by + dy).0.map(f64::from));
        let mean = [0, 1, 2].map(|c| block.iter().map(|p| p[c]).sum::<f64>() / 4.0);
        for pixel in block {
            let off = [0, 1, 2].map(|c| pixel[c] - mean[c]);
            let grey = off.iter().sum::<f64>() / 3.0;
            squares += off.iter().map(|o| (o - grey).powi(2)).sum::<f64>();
        }
    }
    10.0 * (255.0f64 * 255.0 * (width * height * 3) as f64 / squares).log10()
}

fn ok(d: &Path, args: &[&str]) -> Run {
    let r = run(d, args);
    assert_eq!(r.code, 0, "{args:?}: {}", r.stderr);
    r
}

#[test]
fn a_nerfstudio_path_renders_to_an_mp4_and_a_gif_whose_first_frame_is_the_pose() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let poses = opengl_poses(6);
    let fov = 40.0;
    for size in [(160, 120), (128, 96), (80, 60)] {
        std::fs::write(d.join("camera_path.json"), nerfstudio_path(&poses, size, 12.0, fov).to_string()).unwrap();
        let r = ok(d, &["--camera-path", "camera_path.json", "--out", "path.mp4"]);
        // stderr is a pipe here: no progress bar, only the note that this is not a GPU.
        assert!(r.stderr.lines().all(|l| l.starts_with("render-frame: note")), "{}", r.stderr);
        let video = probe(&d.join("path.mp4"));
        assert_eq!((video.frames, video.width, video.height, video.codec.as_str()), (6, size.0, size.1, "h264"));
        assert!((video.seconds - 0.5).abs() < 1e-6, "6 frames at the path's 12 fps: {video:?}");

        std::fs::write(d.join("pose.json"), pose_file(&poses[0], size, fov).to_string()).unwrap();
        ok(d, &["--pose", "pose.json", "--out", "posed.png"]);
        let (first, posed) = (&decoded_frames(&d.join("path.mp4"))[0], png(&d.join("posed.png")));
        let db = psnr(first, &posed);
        assert!(db >= 40.0, "{size:?}: {db:.2} dB ({})", video.profile);
        // --mp4 auto: 4:2:0 keeps one colour per 2x2 pixels, at 80x60 no such video can pass 39.6 dB on this
        // frame (chroma_420_ceiling), so the video is lossless; at 160x120 the compact one has 42.6 dB.
        if size == (80, 60) {
            assert!(chroma_420_ceiling(&posed) < 40.0);
            assert_eq!((video.profile.as_str(), db), (LOSSLESS, f64::INFINITY));
        }
        if size == (160, 120) {
            assert_eq!(video.profile, COMPACT);
        }

        ok(d, &["--camera-path", "camera_path.json", "--out", "path.gif"]);
        let gif = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(
            std::fs::File::open(d.join("path.gif")).unwrap(),
        ))
        .unwrap();
        let gif_frames: Vec<_> = image::AnimationDecoder::into_frames(gif).collect::<Result<_, _>>().unwrap();
        assert_eq!(gif_frames.len(), 6);
        let first = image::DynamicImage::ImageRgba8(gif_frames[0].buffer().clone()).to_rgb8();
        assert!(psnr(&first, &posed) >= 30.0, "{size:?}: GIF {} dB", psnr(&first, &posed));
    }
    // --fps overrides the path's; the duration follows.
    ok(d, &["--camera-path", "camera_path.json", "--out", "slow.mp4", "--fps", "3"]);
    assert!((probe(&d.join("slow.mp4")).seconds - 2.0).abs() < 1e-6);
}

#[test]
fn mp4_encodings_lossless_is_exact_at_any_size_and_compact_stays_4_2_0() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    // 72x40 and 81x61 are not multiples of 16: the stream crops its last macroblocks.
    let srt = |f: &str| golden("srt_k1", f);
    let odd: &[&str] = &["--model", &srt("model.safetensors"), "--scene", &srt("scene.safetensors"), "--size", "81x61"];
    // Auto is lossless where compact cannot encode the size at all: odd sides, or under OpenH264's 16 pixels.
    let cases = [
        (&["--size", "72x40"][..], (72, 40), "lossless"),
        (odd, (81, 61), "auto"),
        (&["--size", "12x8"], (12, 8), "auto"),
    ];
    for (model, size, mode) in cases {
        let orbit = |more: &[&str]| ok(d, &[model, &["--motion", "orbit", "--frames", "2"], more].concat());
        orbit(&["--out", "frames"]);
        orbit(&["--mp4", mode, "--out", "lossless.mp4"]);
        let video = probe(&d.join("lossless.mp4"));
        assert_eq!((video.frames, video.width, video.height), (2, size.0, size.1));
        assert_eq!((video.profile.as_str(), video.pix_fmt.as_str()), (LOSSLESS, "gbrp"));
        assert!((video.seconds - 2.0 / 24.0).abs() < 1e-6, "{video:?}");
        for (i, frame) in decoded_frames(&d.join("lossless.mp4")).iter().enumerate() {
            assert!(*frame == png(&d.join(format!("frames/frame_{i:03}.png"))), "{size:?}: frame {i} is not exact");
        }
    }
    // Compact stays 4:2:0 even where auto would not (80x60, the bundled model): close, not exact.
    ok(d, &["--motion", "orbit", "--frames", "2", "--out", "frames"]);
    ok(d, &["--motion", "orbit", "--frames", "2", "--mp4", "compact", "--out", "compact.mp4"]);
    let video = probe(&d.join("compact.mp4"));
    assert_eq!((video.frames, video.profile.as_str(), video.pix_fmt.as_str()), (2, COMPACT, "yuvj420p"));
    let db = psnr(&decoded_frames(&d.join("compact.mp4"))[0], &png(&d.join("frames/frame_000.png")));
    assert!((35.0..40.0).contains(&db), "{db:.2} dB");
}

#[test]
fn every_motion_and_interpolation_renders_its_frames() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    ok(d, &["--out", "view0.png"]);
    ok(d, &["--view", "1", "--out", "view1.png"]);
    let mut firsts = Vec::new();
    for motion in ["orbit", "spiral", "zoom", "closeup", "eyeroll"] {
        ok(d, &["--motion", motion, "--frames", "5", "--out", motion]);
        let frames: Vec<_> = (0..5).map(|i| png(&d.join(format!("{motion}/frame_{i:03}.png")))).collect();
        assert!(frames.iter().all(|f| f.dimensions() == (80, 60)));
        assert!(frames.windows(2).all(|w| w[0] != w[1]), "{motion}: every frame moves");
        firsts.push((motion, frames[0].clone(), frames[4].clone()));
    }
    // The presets start from the first target camera, which looks at the scene's centre (the origin); the
    // spiral starts 20° lower and the eyeroll looks beside the centre.
    let view0 = png(&d.join("view0.png"));
    for (motion, first, _) in &firsts {
        if !matches!(*motion, "spiral" | "eyeroll") {
            assert!(psnr(first, &view0) > 40.0, "{motion}: {} dB against target view 0", psnr(first, &view0));
        }
    }
    ok(d, &["--interpolate", "--view", "0,1", "--frames", "4", "--out", "between"]);
    assert!(psnr(&png(&d.join("between/frame_000.png")), &view0) > 40.0);
    assert!(psnr(&png(&d.join("between/frame_003.png")), &png(&d.join("view1.png"))) > 40.0);
    // A camera path's cameras as keys.
    std::fs::write(d.join("keys.json"), nerfstudio_path(&opengl_poses(3), (80, 60), 24.0, 40.0).to_string()).unwrap();
    ok(d, &["--camera-path", "keys.json", "--out", "keys"]);
    ok(d, &["--camera-path", "keys.json", "--interpolate", "--frames", "5", "--out", "smooth"]);
    assert!(psnr(&png(&d.join("smooth/frame_004.png")), &png(&d.join("keys/frame_002.png"))) > 40.0);
    // Elevation and radius move the start camera.
    ok(d, &["--motion", "orbit", "--frames", "2", "--elevation", "60", "--radius", "8", "--out", "high"]);
    assert!(psnr(&png(&d.join("high/frame_000.png")), &view0) < 25.0);
    // The old turntable flag still works.
    ok(d, &["--orbit-frames", "3", "--out", "turntable.mp4"]);
    assert_eq!(probe(&d.join("turntable.mp4")).frames, 3);
}

#[test]
fn size_fov_and_panels() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    ok(d, &["--motion", "zoom", "--frames", "2", "--size", "160x120", "--out", "big"]);
    assert_eq!(png_size(&d.join("big/frame_000.png")), (160, 120));
    ok(d, &["--motion", "zoom", "--frames", "2", "--fov", "20", "--out", "narrow"]);
    ok(d, &["--motion", "zoom", "--frames", "2", "--out", "normal"]);
    assert!(psnr(&png(&d.join("narrow/frame_000.png")), &png(&d.join("normal/frame_000.png"))) < 25.0);
    ok(d, &["--orbit", "30", "--size", "120x88", "--out", "orbit.png"]);
    assert_eq!(png_size(&d.join("orbit.png")), (120, 88));

    // Depth panels share one range: every frame's colour bar and labels are the same pixels.
    let golden_depth = |f: &str| golden("srt_k1_depth", f);
    let (model, scene) = (golden_depth("model.safetensors"), golden_depth("scene.safetensors"));
    let orbit = |more: &[&str]| {
        let args = ["--model", &model, "--scene", &scene, "--motion", "orbit", "--frames", "3"];
        ok(d, &[&args[..], more].concat())
    };
    orbit(&["--panels", "rgb,depth,input", "--out", "panels"]);
    let frames: Vec<_> = (0..3).map(|i| png(&d.join(format!("panels/frame_{i:03}.png")))).collect();
    let (w, h) = frames[0].dimensions();
    assert!(w > 3 * 24 && h > 16 && w % 2 == 0 && h % 2 == 0, "{w}x{h}");
    let legend = |f: &image::RgbImage| f.rows().skip(h as usize - 10).flat_map(|r| r.map(|p| p.0)).collect::<Vec<_>>();
    assert!(frames.iter().all(|f| legend(f) == legend(&frames[0])), "one depth range for the whole sequence");
    assert!(frames[0] != frames[1]);
    orbit(&["--panels", "depth", "--depth-range", "1,9", "--out", "ranged.mp4"]);
    assert_eq!(probe(&d.join("ranged.mp4")).frames, 3);
    let osrt = |f: &str| golden("osrt", f);
    ok(
        d,
        &[
            "--model",
            &osrt("model.safetensors"),
            "--scene",
            &osrt("scene.safetensors"),
            "--motion",
            "spiral",
            "--frames",
            "2",
            "--panels",
            "rgb,segmentation",
            "--out",
            "masks.gif",
        ],
    );
}

#[test]
fn bad_sequences_are_one_line_errors_with_nothing_written() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    fails(
        d,
        &["--motion", "orbit", "--size", "81x60", "--out", "x.mp4"],
        &["--size", "81x60", "k=4", "nearest valid sizes: 80x60, 84x60"],
    );
    // Each refused extension with its own reason.
    fails(d, &["--motion", "orbit", "--out", "x.webp"], &["x.webp", "animated WebP", ".mp4"]);
    fails(d, &["--motion", "orbit", "--out", "x.webm"], &["x.webm", "VP8", ".mp4"]);
    fails(d, &["--motion", "orbit", "--out", "x.mkv"], &["x.mkv", ".mkv files are not written", ".mp4"]);
    for (size, text) in [("12x8", "12x8"), ("16x12", "16x12")] {
        fails(
            d,
            &["--motion", "orbit", "--size", size, "--mp4", "compact", "--out", "x.mp4"],
            &["x.mp4", text, "at least 16 pixels", "--size 16x16", "--mp4 lossless"],
        );
    }
    fails(d, &["--motion", "orbit", "--size", "4000x2000", "--out", "x.mp4"], &["x.mp4", "3840x2160"]);
    fails(d, &["--frames", "3", "--out", "x.mp4"], &["--frames", "--motion"]);
    fails(d, &["--motion", "twirl"], &["twirl", "orbit, spiral, zoom, closeup, eyeroll"]);
    fails(d, &["--motion", "orbit", "--fov", "180"], &["--fov", "(0, 180)"]);
    fails(d, &["--motion", "orbit", "--size", "0x60"], &["--size"]);
    fails(d, &["--motion", "orbit", "--size", "100000x60"], &["--size"]);
    fails(d, &["--motion", "orbit", "--frames", "0"], &["--frames 0"]);
    fails(d, &["--motion", "orbit", "--panels", "rgb,depth"], &["--panels depth", "depth"]);
    fails(d, &["--motion", "orbit", "--panels", "rgb,colour"], &["colour", "rgb, depth, segmentation, input"]);
    fails(d, &["--motion", "orbit", "--depth-range", "1,2"], &["--depth-range"]);
    fails(d, &["--motion", "orbit", "--fps", "10", "--out", "frames"], &["--fps", "frames"]);
    fails(d, &["--motion", "orbit", "--out", "x.mp4", "--mp4", "best"], &["--mp4", "best", "auto, compact, lossless"]);
    fails(d, &["--motion", "orbit", "--mp4", "lossless", "--out", "x.gif"], &["--mp4", "x.gif"]);
    fails(d, &["--size", "160x120", "--metrics"], &["--size"]);
    let srt = |f: &str| golden("srt_k1", f);
    fails(
        d,
        &[
            "--model",
            &srt("model.safetensors"),
            "--scene",
            &srt("scene.safetensors"),
            "--motion",
            "orbit",
            "--size",
            "81x61",
            "--mp4",
            "compact",
            "--out",
            "odd.mp4",
        ],
        &["odd.mp4", "even", "82x62", "--mp4 lossless"],
    );
    // A bad camera path for a video: the same one-line errors, no file.
    let mut bad = nerfstudio_path(&opengl_poses(2), (80, 60), 24.0, 40.0);
    bad["camera_path"][1]["camera_to_world"] = json!([1, 0, 0]);
    std::fs::write(d.join("bad.json"), bad.to_string()).unwrap();
    fails(d, &["--camera-path", "bad.json", "--out", "x.mp4"], &["bad.json", "`camera_path` 1", "16 finite numbers"]);
    std::fs::remove_file(d.join("bad.json")).unwrap();
}

/// The figures in docs/CAMERA_PATHS.md: the MP4's first frame against the PNG of its pose, by size, compact
/// (with the 4:2:0 ceiling) and auto, with the files' sizes (`cargo test --release -p raypatch-cli --test video
/// -- --ignored --nocapture`).
#[test]
#[ignore = "measures; asserts nothing"]
fn mp4_first_frame_psnr_by_size() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let poses = opengl_poses(6);
    for size in [(64, 64), (80, 60), (96, 72), (128, 96), (160, 120), (320, 240)] {
        std::fs::write(d.join("camera_path.json"), nerfstudio_path(&poses, size, 12.0, 40.0).to_string()).unwrap();
        std::fs::write(d.join("pose.json"), pose_file(&poses[0], size, 40.0).to_string()).unwrap();
        ok(d, &["--pose", "pose.json", "--out", "posed.png"]);
        let posed = png(&d.join("posed.png"));
        let mut line = format!("{}x{} (4:2:0 ceiling {:.2} dB):", size.0, size.1, chroma_420_ceiling(&posed));
        for mode in ["compact", "auto"] {
            ok(d, &["--camera-path", "camera_path.json", "--mp4", mode, "--out", "path.mp4"]);
            let db = psnr(&decoded_frames(&d.join("path.mp4"))[0], &posed);
            let bytes = std::fs::metadata(d.join("path.mp4")).unwrap().len();
            line +=
                &format!(" {mode} {db:.2} dB, {bytes} bytes for 6 frames ({});", probe(&d.join("path.mp4")).profile);
        }
        println!("{line}");
    }
}
