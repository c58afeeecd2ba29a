//! Which cameras a run renders: the scene's target views, a pose, a turntable, a camera path, a motion preset
//! or an interpolation, each at the size and field of view asked for.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use glam::DVec3;
use raypatch::{Camera, Image, Intrinsics, Motion, MotionOptions, RayKind, SceneData};

use crate::parse::{parse_count, parse_degrees, parse_motion, parse_point, parse_radius, parse_size, parse_up};

/// Frames of a motion or an interpolation when --frames is not given.
const DEFAULT_FRAMES: usize = 36;

#[derive(clap::Args, Debug)]
pub struct CameraArgs {
    /// Render the first target camera turned by DEG degrees about the world z axis (a novel view).
    #[arg(long, value_name = "DEG", allow_hyphen_values = true, conflicts_with = "pose")]
    pub orbit: Option<f64>,
    /// Render from the camera in FILE: JSON with a 4x4 camera-to-world `transform_matrix` (NeRF axes) and
    /// optional intrinsics (`camera_angle_x` or `fl_x`/`fl_y`/`cx`/`cy`, `w`/`h`).
    #[arg(long, value_name = "FILE")]
    pub pose: Option<PathBuf>,
    /// Render a turntable of N frames (360/N degrees apart, about the world z axis through the origin) of the
    /// first target camera, starting at --orbit degrees.
    #[arg(long, value_name = "N", conflicts_with = "pose", value_parser = parse_count)]
    pub orbit_frames: Option<usize>,
    /// Render every camera of a camera path: nerfstudio's camera_path.json (`render_width`/`render_height`,
    /// `camera_path` of `camera_to_world` and vertical `fov`; perspective only) or raypatch's form (`width`,
    /// `height`, `frames`) (README, "Camera paths").
    #[arg(long, value_name = "FILE", conflicts_with_all = ["pose", "orbit", "orbit_frames", "view"])]
    pub camera_path: Option<PathBuf>,
    /// A camera motion about the scene's centre, from the first target camera: orbit, spiral, zoom, closeup
    /// or eyeroll (docs/CAMERA_PATHS.md).
    #[arg(long, value_name = "NAME", value_parser = parse_motion,
          conflicts_with_all = ["pose", "orbit", "orbit_frames", "camera_path", "interpolate"])]
    pub motion: Option<Motion>,
    /// Frames of --motion or --interpolate [default: 36].
    #[arg(long, value_name = "N", value_parser = parse_count)]
    pub frames: Option<usize>,
    /// --motion: the start camera's elevation above the centre's level plane, degrees [default: its own].
    #[arg(long, value_name = "DEG", allow_hyphen_values = true, value_parser = parse_degrees, requires = "motion")]
    pub elevation: Option<f64>,
    /// --motion: the start camera's distance from the centre [default: its own].
    #[arg(long, value_name = "R", value_parser = parse_radius, requires = "motion")]
    pub radius: Option<f64>,
    /// --motion: the point looked at [default: the point nearest to the optical axes of the scene's cameras].
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, value_parser = parse_point, requires = "motion")]
    pub centre: Option<DVec3>,
    /// --motion: the world's up axis, x, y, z, -x, -y or -z [default: the axis nearest the scene cameras' up].
    #[arg(long, value_name = "AXIS", allow_hyphen_values = true, value_parser = parse_up, requires = "motion")]
    pub up: Option<DVec3>,
    /// --motion: ease in and out (start and stop smoothly).
    #[arg(long, requires = "motion")]
    pub fade: bool,
    /// Render --frames cameras along a smooth path through the key cameras: the --camera-path's cameras, the
    /// --view target views when given, else the scene's cameras, inputs then targets (Catmull-Rom positions,
    /// slerped rotations).
    #[arg(long, conflicts_with_all = ["pose", "orbit", "orbit_frames"])]
    pub interpolate: bool,
    /// Render every camera at this size, keeping its vertical field of view (the model's k must divide it).
    #[arg(long, value_name = "WxH", value_parser = parse_size)]
    pub size: Option<(usize, usize)>,
    /// Render every camera with this vertical field of view in degrees, in (0, 180), square pixels.
    #[arg(long, value_name = "DEG", allow_hyphen_values = true, value_parser = parse_degrees)]
    pub fov: Option<f64>,
}

/// One image to render, and its name in an output folder.
pub struct Shot {
    pub camera: Camera,
    /// The target view's ground truth, for --metrics.
    pub truth: Option<Image>,
    /// The target view's object ids, for --metrics (FG-ARI).
    pub masks: Option<Vec<u32>>,
    /// The target view's depth in metres, for --metrics (Abs.Rel, Sq.Rel, RMSE).
    pub depth: Option<Vec<f32>>,
    pub label: String,
    pub name: String,
}

impl Shot {
    /// A camera without ground truth (a novel view).
    pub fn novel(camera: Camera, label: String, name: String) -> Shot {
        Shot { camera, truth: None, masks: None, depth: None, label, name }
    }

    fn frames(cameras: Vec<Camera>, what: &str) -> Vec<Shot> {
        (cameras.into_iter().enumerate())
            .map(|(i, camera)| Shot::novel(camera, format!("{what} frame {i}"), format!("frame_{i:03}")))
            .collect()
    }
}

/// The cameras to render, and the camera path's frame rate when it gives one. `views` are the chosen target
/// views (`views_given`: by --view), `kind` the model's ray kind.
pub fn shots(
    args: &CameraArgs,
    data: &SceneData,
    views: &[usize],
    views_given: bool,
    kind: RayKind,
) -> Result<(Vec<Shot>, Option<f64>)> {
    if args.frames.is_some() && args.motion.is_none() && !args.interpolate {
        bail!("--frames: only with --motion or --interpolate (--orbit-frames N for the turntable)");
    }
    let frames = args.frames.unwrap_or(DEFAULT_FRAMES);
    if frames == 0 {
        bail!("--frames 0: expected at least one frame");
    }
    let reference = &data.targets[views[0]].camera;
    let pinhole = |camera: &Camera| raypatch::fit_pinhole(camera, kind);
    let path = args.camera_path.as_ref().map(raypatch::load_camera_path).transpose()?;
    let fps = path.as_ref().and_then(|p| p.fps);
    let shots = if let Some(motion) = args.motion {
        let start = pinhole(reference).context("--motion: the first target camera")?;
        let start = (sized(args, start.0)?, start.1);
        let cameras = (data.inputs.iter().map(|v| &v.camera)).chain(data.targets.iter().map(|t| &t.camera));
        let scene = raypatch::fitted_poses(cameras, kind)?;
        let options = MotionOptions {
            elevation: args.elevation,
            radius: args.radius,
            fade: args.fade,
            ..MotionOptions::about(&scene, frames, args.centre, args.up).context("--motion (give --centre X,Y,Z)")?
        };
        let cameras =
            raypatch::motion_path(motion, start, &options).with_context(|| format!("--motion {}", motion.name()))?;
        Shot::frames(cameras, motion.name())
    } else if args.interpolate {
        let keys: Vec<&Camera> = match (&path, views_given) {
            (Some(path), _) => path.cameras.iter().collect(),
            (None, true) => views.iter().map(|&v| &data.targets[v].camera).collect(),
            (None, false) => {
                (data.inputs.iter().map(|v| &v.camera)).chain(data.targets.iter().map(|t| &t.camera)).collect()
            }
        };
        let keys = (keys.into_iter())
            .map(|c| pinhole(c).and_then(|(k, pose)| Ok((raypatch::resized(k, args.size, args.fov)?, pose))))
            .collect::<raypatch::Result<Vec<_>>>()
            .context("--interpolate")?;
        Shot::frames(raypatch::interpolate(&keys, frames).context("--interpolate")?, "interpolated")
    } else if let Some(path) = path {
        Shot::frames(resize_all(args, path.cameras, kind)?, "camera path")
    } else {
        let shots = single_shots(args, data, views)?;
        if args.size.is_some() || args.fov.is_some() {
            if shots.iter().any(|s| s.truth.is_some()) {
                bail!("--size/--fov: not for the scene's target views (their ground truth is of their own size); use --orbit, --pose or a sequence");
            }
            let cameras = resize_all(args, shots.iter().map(|s| s.camera.clone()).collect(), kind)?;
            shots.into_iter().zip(cameras).map(|(s, camera)| Shot { camera, ..s }).collect()
        } else {
            shots
        }
    };
    Ok((shots, fps))
}

/// `intrinsics` at --size and --fov.
fn sized(args: &CameraArgs, intrinsics: Intrinsics) -> Result<Intrinsics> {
    raypatch::resized(intrinsics, args.size, args.fov).context("--size/--fov")
}

fn resize_all(args: &CameraArgs, cameras: Vec<Camera>, kind: RayKind) -> Result<Vec<Camera>> {
    if args.size.is_none() && args.fov.is_none() {
        return Ok(cameras);
    }
    (cameras.iter())
        .map(|camera| {
            let (k, pose) = raypatch::fit_pinhole(camera, kind)?;
            Ok(Camera::pinhole(sized(args, k)?, pose, raypatch::CameraAxes::OpenCv)?)
        })
        .collect()
}

/// The target views, a pose, a turntable or one orbited view.
fn single_shots(args: &CameraArgs, data: &SceneData, views: &[usize]) -> Result<Vec<Shot>> {
    let reference = &data.targets[views[0]].camera;
    if let Some(degrees) = args.orbit.filter(|d| !d.is_finite()) {
        bail!("--orbit {degrees}: expected a finite angle in degrees");
    }
    if let Some(path) = &args.pose {
        let camera = raypatch::load_pose(path, reference)?;
        Ok(vec![Shot::novel(camera, format!("--pose {}", path.display()), "render".into())])
    } else if let Some(n) = args.orbit_frames {
        if n == 0 {
            bail!("--orbit-frames 0: expected at least one frame");
        }
        let start = args.orbit.unwrap_or(0.0);
        let turn = |i: usize| start + 360.0 * i as f64 / n as f64;
        Ok((0..n)
            .map(|i| {
                let label = format!("turntable frame {i} ({:.1}°)", turn(i));
                Shot::novel(reference.orbited(turn(i)), label, format!("frame_{i:03}"))
            })
            .collect())
    } else if let Some(degrees) = args.orbit {
        Ok(vec![Shot::novel(reference.orbited(degrees), format!("--orbit {degrees}"), "render".into())])
    } else {
        Ok(views
            .iter()
            .map(|&v| Shot {
                camera: data.targets[v].camera.clone(),
                truth: data.targets[v].image.clone(),
                masks: data.targets[v].masks.clone(),
                depth: data.targets[v].depth.clone(),
                label: format!("target view {v}"),
                name: format!("view_{v:03}"),
            })
            .collect())
    }
}

/// Checks that the model renders every shot's image size (`raypatch::input::check_patch_size`), before any
/// output is started.
pub fn check_patch_size(shots: &[Shot], sizes: raypatch::PatchSize, size_flag: bool) -> Result<()> {
    for shot in shots {
        let (w, h) = (shot.camera.width(), shot.camera.height());
        let what = if size_flag { "--size".to_string() } else { shot.label.clone() };
        raypatch::input::check_patch_size(sizes, w, h).with_context(|| what)?;
    }
    Ok(())
}
