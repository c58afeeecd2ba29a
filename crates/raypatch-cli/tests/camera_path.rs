//! `render-frame --camera-path`: nerfstudio's camera_path.json (written here by hand in its format, as its
//! viewer exports it) and raypatch's own form render every camera, each frame as a `--pose` render of the same
//! camera, to PNG frames or an animated GIF; bad paths are one-line errors with exit code 2 and nothing written.

mod common;

use common::*;
use glam::{DMat4, DVec3};
use raypatch::Camera;
use serde_json::{json, Value};
use tempfile::TempDir;

/// Camera-to-world poses with OpenGL axes of MSN-style cameras around the bundled scene.
fn opengl_poses() -> Vec<DMat4> {
    [DVec3::new(9.0, -3.0, 5.0), DVec3::new(-6.0, 7.0, 4.0), DVec3::new(2.0, 9.5, 6.0)]
        .into_iter()
        .map(|eye| {
            let (_, cv) = Camera::msn(eye, 80, 60).unwrap().as_pinhole().unwrap();
            DMat4::from_cols(cv.x_axis, -cv.y_axis, -cv.z_axis, cv.w_axis)
        })
        .collect()
}

fn row_major(m: &DMat4) -> Vec<f64> {
    m.transpose().to_cols_array().to_vec()
}

fn nerfstudio_path(poses: &[DMat4], fov: f64) -> Value {
    let cameras: Vec<Value> =
        poses.iter().map(|p| json!({"camera_to_world": row_major(p), "fov": fov, "aspect": 4.0 / 3.0})).collect();
    json!({"camera_type": "perspective", "render_width": 80, "render_height": 60, "fps": 24, "seconds": 2,
           "smoothness_value": 0.5, "is_cycle": false, "crop": null, "keyframes": [], "camera_path": cameras})
}

#[test]
fn nerfstudio_and_raypatch_paths_render_each_camera_as_a_pose_does() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let poses = opengl_poses();
    let fov: f64 = 40.0;
    std::fs::write(d.join("camera_path.json"), nerfstudio_path(&poses, fov).to_string()).unwrap();
    let r = run(d, &["--camera-path", "camera_path.json", "--out", "path"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert!(r.stdout.contains("rendered 3 view(s) of 80x60"), "{}", r.stdout);

    // Each frame is the render of its pose with the intrinsics the fov gives: (height / 2) / tan(fov / 2).
    let focal = 30.0 / (fov.to_radians() / 2.0).tan();
    for (i, pose) in poses.iter().enumerate() {
        let rows: Vec<Vec<f64>> = (0..4).map(|r| pose.row(r).to_array().to_vec()).collect();
        let file = json!({"fl_x": focal, "fl_y": focal, "w": 80, "h": 60, "transform_matrix": rows});
        std::fs::write(d.join("pose.json"), file.to_string()).unwrap();
        let r = run(d, &["--pose", "pose.json", "--out", "posed.png"]);
        assert_eq!(r.code, 0, "{}", r.stderr);
        let frame = std::fs::read(d.join(format!("path/frame_{i:03}.png"))).unwrap();
        assert_eq!(frame, std::fs::read(d.join("posed.png")).unwrap(), "frame {i}");
    }

    // raypatch's form with OpenCV axes and focal lengths: the same cameras, the same frames.
    let frames: Vec<Value> = poses
        .iter()
        .map(|p| json!({"camera_to_world": (0..4).map(|r| (*p * DMat4::from_diagonal(glam::DVec4::new(1.0, -1.0, -1.0, 1.0))).row(r).to_array().to_vec()).collect::<Vec<_>>()}))
        .collect();
    let own = json!({"width": 80, "height": 60, "convention": "opencv", "fl_x": focal, "frames": frames});
    std::fs::write(d.join("own.json"), own.to_string()).unwrap();
    let r = run(d, &["--camera-path", "own.json", "--out", "own"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    for i in 0..poses.len() {
        let name = format!("frame_{i:03}.png");
        assert_eq!(
            std::fs::read(d.join("own").join(&name)).unwrap(),
            std::fs::read(d.join("path").join(&name)).unwrap()
        );
    }
}

/// The frames of a GIF file as RGB images, with each frame's delay in milliseconds.
fn gif_frames(path: &std::path::Path) -> Vec<(image::RgbImage, u32)> {
    use image::AnimationDecoder;
    let decoder =
        image::codecs::gif::GifDecoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap())).unwrap();
    (decoder.into_frames().map(|f| f.unwrap()))
        .map(|f| {
            let (numer, denom) = f.delay().numer_denom_ms();
            (image::DynamicImage::ImageRgba8(f.into_buffer()).to_rgb8(), numer / denom)
        })
        .collect()
}

fn psnr(a: &image::RgbImage, b: &image::RgbImage) -> f64 {
    let mse = a.as_raw().iter().zip(b.as_raw()).map(|(&x, &y)| (x as f64 - y as f64).powi(2)).sum::<f64>()
        / a.as_raw().len() as f64;
    10.0 * (255.0f64 * 255.0 / mse).log10()
}

#[test]
fn a_camera_path_renders_to_an_animated_gif_at_its_frame_rate() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    std::fs::write(d.join("camera_path.json"), nerfstudio_path(&opengl_poses(), 40.0).to_string()).unwrap();
    let r = run(d, &["--camera-path", "camera_path.json", "--out", "path"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    let r = run(d, &["--camera-path", "camera_path.json", "--out", "path.gif"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    let frames = gif_frames(&d.join("path.gif"));
    assert_eq!(frames.len(), 3);
    for (i, (frame, delay)) in frames.iter().enumerate() {
        assert_eq!(frame.dimensions(), (80, 60));
        assert_eq!(*delay, 40, "24 fps: 4 hundredths of a second a frame");
        let png = image::open(d.join(format!("path/frame_{i:03}.png"))).unwrap().to_rgb8();
        assert!(psnr(frame, &png) >= 30.0, "frame {i}: {} dB against the PNG", psnr(frame, &png));
    }
    let r = run(d, &["--camera-path", "camera_path.json", "--out", "slow.gif", "--fps", "5"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert!(gif_frames(&d.join("slow.gif")).iter().all(|(_, delay)| *delay == 200));
    fails(d, &["--orbit-frames", "2", "--out", "x.gif", "--fps", "0"], &["--fps", "1 to 100"]);
    fails(d, &["--orbit-frames", "2", "--out", "x.png", "--fps", "10"], &["--fps", "x.png"]);
}

#[test]
fn bad_camera_paths_are_one_line_errors() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let good = nerfstudio_path(&opengl_poses(), 40.0);
    let write = |name: &str, text: String| {
        std::fs::write(d.join(name), text).unwrap();
        name.to_string()
    };
    let edited = |name: &str, edit: &dyn Fn(&mut Value)| {
        let mut value = good.clone();
        edit(&mut value);
        write(name, value.to_string())
    };
    let cases: Vec<(String, Vec<&str>)> = vec![
        (write("text.json", "not json".into()), vec!["text.json", "not valid JSON"]),
        (write("list.json", "[1, 2]".into()), vec!["list.json", "camera_path"]),
        (edited("fisheye.json", &|v| v["camera_type"] = json!("fisheye")), vec!["fisheye.json", "perspective"]),
        (
            edited("short.json", &|v| v["camera_path"][1]["camera_to_world"] = json!([1, 0, 0, 0])),
            vec!["short.json", "`camera_path` 1", "16 finite numbers"],
        ),
        (
            edited("nan.json", &|v| v["camera_path"][0]["camera_to_world"][3] = json!("NaN")),
            vec!["nan.json", "`camera_path` 0", "16 finite numbers"],
        ),
        (
            edited("scaled.json", &|v| v["camera_path"][2]["camera_to_world"][0] = json!(2.0)),
            vec!["scaled.json", "`camera_path` 2", "orthonormal"],
        ),
        (
            edited("zero.json", &|v| v["render_width"] = json!(0)),
            vec!["zero.json", "render_width", "whole number of pixels"],
        ),
        (edited("huge.json", &|v| v["render_height"] = json!(1e9)), vec!["huge.json", "render_height"]),
        (edited("fov0.json", &|v| v["camera_path"][0]["fov"] = json!(0)), vec!["fov0.json", "(0, 180)"]),
        (edited("fov180.json", &|v| v["camera_path"][1]["fov"] = json!(180)), vec!["fov180.json", "(0, 180)"]),
        (
            edited("nofov.json", &|v| {
                v["camera_path"][0].as_object_mut().unwrap().remove("fov");
            }),
            vec!["nofov.json", "no `fov`"],
        ),
        (edited("empty.json", &|v| v["camera_path"] = json!([])), vec!["empty.json", "1 to"]),
        (edited("odd.json", &|v| v["render_width"] = json!(82)), vec!["82", "patch size k=4"]),
    ];
    for (file, expected) in &cases {
        fails(d, &["--camera-path", file, "--out", "frames"], expected);
    }
    fails(d, &["--camera-path", "absent.json"], &["absent.json", "cannot read"]);
}
