//! The viewer's answers to bad camera input come from the API's error kind (`raypatch::Error::kind`, mapped by
//! `http::status_of`): a size the model's patch size does not divide and a pose that is not rigid are 400s with
//! one line naming the parameter, never 500s.

use glam::DVec3;
use raypatch::{Camera, ErrorKind, PatchSize};
use raypatch_viewer::catalog::{ModelEntry, SceneEntry, ViewOutput};
use raypatch_viewer::http::{parse_head, status_of, HttpError};
use raypatch_viewer::query::parse_render;

/// The viewer's answer to `GET target` for one RP-SRT k=4 model and one 80x60 scene, when it refuses it.
fn refusal(target: &str) -> HttpError {
    let models = [ModelEntry {
        name: "model.safetensors".into(),
        family: "RP-SRT k=4".into(),
        sizes: PatchSize { k: 4, any_size: false },
        outputs: vec![ViewOutput::Rgb],
        computes: "precision f32".into(),
    }];
    let scenes = [SceneEntry {
        name: "scene.safetensors".into(),
        reference: Camera::msn(DVec3::new(4.0, -3.0, 2.0), 80, 60).unwrap(),
        input_cameras: vec![],
        target_cameras: vec![],
        thumbnails: vec![],
    }];
    let request = parse_head(format!("GET {target} HTTP/1.1").as_bytes()).unwrap();
    parse_render(&request.query, &models, &scenes).expect_err(target)
}

/// The response's status and its body, which must be one line.
fn answered(error: &HttpError) -> (u16, String) {
    let bytes = error.response().into_bytes();
    let text = String::from_utf8(bytes).unwrap();
    let body = text.split_once("\r\n\r\n").unwrap().1.to_string();
    assert_eq!(body.lines().count(), 1, "{body:?}");
    (error.status, body)
}

#[test]
fn a_size_the_patch_size_does_not_divide_is_a_400_naming_the_nearest_sizes() {
    let (status, body) = answered(&refusal("/render.png?size=50x30"));
    assert_eq!(status, 400, "{body}");
    assert!(body.starts_with("size: target size 50x30"), "{body}");
    assert!(body.contains("k=4; nearest valid sizes: 48x28, 48x32, 52x28, 52x32"), "{body}");
}

#[test]
fn a_pose_that_is_not_rigid_is_a_400() {
    let scaled = "2,0,0,0,0,2,0,0,0,0,2,0,0,0,0,1";
    let (status, body) = answered(&refusal(&format!("/render.png?pose={scaled}")));
    assert_eq!(status, 400, "{body}");
    assert!(body.starts_with("pose rotation is not orthonormal"), "{body}");
    let (status, body) = answered(&refusal("/render.png?pose=NaN,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1"));
    assert_eq!((status, body.starts_with("pose: number 0 is NaN")), (400, true), "{body}");
    let (status, body) = answered(&refusal("/render.png?pose=1,0,0,0,0,1,0,0,0,0,1,0,1,0,0,1"));
    assert_eq!((status, body.contains("bottom row")), (400, true), "{body}");
}

#[test]
fn every_error_kind_has_its_status() {
    let statuses = [ErrorKind::Input, ErrorKind::File, ErrorKind::Device, ErrorKind::Internal].map(status_of);
    assert_eq!(statuses, [400, 422, 503, 500]);
    let convention = "blender".parse::<raypatch::CameraAxes>().unwrap_err();
    assert_eq!(HttpError::of(&convention).status, 400);
}
