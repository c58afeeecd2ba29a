//! # raypatch
//!
//! Novel-view rendering with Light Field Transformers (SRT, OSRT and DeFiNe, and their Ray-Patch variants
//! RP-SRT, RP-OSRT and RP-DeFiNe) on hand-written WGSL compute shaders, on any GPU through wgpu, or on the CPU
//! through Mesa lavapipe.
//!
//! An [`Engine`] picks an adapter; [`Engine::load`] reads a model file; [`Model::encode`] turns posed input
//! images into a [`Scene`] (the latent tokens and the decoder's keys and values, computed once);
//! [`Scene::render`] renders it from any [`Camera`], computing only the outputs and the region the
//! [`Request`] asks for.
//!
//! ```
//! use glam::DVec3;
//! use raypatch::{Camera, Engine, EngineOptions, Request, SceneData};
//!
//! let golden = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/golden/rpsrt_k4");
//! let engine = Engine::new(EngineOptions::default())?; // a real GPU first, lavapipe otherwise
//! let model = engine.load(format!("{golden}/model.safetensors"))?;
//! let data = SceneData::load(format!("{golden}/scene.safetensors"))?;
//! let scene = model.encode(&data.inputs)?;
//!
//! // A MultiShapeNet-style camera: looks at the origin, z up; 48x32 pixels (Ray-Patch k=4 divides both).
//! let camera = Camera::msn(DVec3::new(7.0, -2.0, 3.0), 48, 32)?;
//! let rendered = scene.render(&camera, &Request::default())?;
//! let rgb = rendered.rgb().expect("rgb is rendered by default");
//! rgb.save_png(std::env::temp_dir().join("raypatch-doc-view.png"))?;
//! assert_eq!((rgb.width(), rgb.height()), (48, 32));
//! # Ok::<(), raypatch::Error>(())
//! ```
//!
//! The crates underneath are re-exported for tools that need more: [`raypatch_model`] (config, file
//! formats) and [`raypatch_engine`] (GPU context, plans, kernels).

mod camera;
mod camera_path;
// Writing files (and removing them on signals) is the native API's: a browser's outputs go back to the page.
#[cfg(not(target_family = "wasm"))]
mod checkpoint;
mod dataset;
mod error;
mod font;
#[doc(hidden)]
pub mod fuzzing;
mod gif;
mod image;
pub mod input;
pub mod metrics;
mod motion;
#[cfg(not(target_family = "wasm"))]
mod output;
mod panels;
mod render;

pub use camera::{
    Camera, Intrinsics, RayGrid, RayKind, MAX_RAY_ANGLE_DEGREES, MIN_FIELD_OF_VIEW_DEGREES, MSN_FOCAL_LENGTH,
    MSN_SENSOR_WIDTH,
};
pub use camera_path::{load_camera_path, CameraPath};
#[cfg(not(target_family = "wasm"))]
pub use checkpoint::save_checkpoint_model;
pub use dataset::{load_pose, SceneData, SceneSource, TargetView, MAX_SCENE_PIXELS};
pub use error::{error_line, exit_code, Error, ErrorKind, Result};
pub use gif::GifWriter;
pub use image::{check_image_size, slot_ids, Image, MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE};
pub use input::{resized, CameraAxes, FieldOfView, PatchSize, MAX_PATH_FRAMES, ROTATION_TOLERANCE};
pub use motion::{fit_pinhole, fitted_poses, interpolate, motion_path, scene_centre, up_axis, Motion, MotionOptions};
#[cfg(not(target_family = "wasm"))]
pub use output::{
    check_output_path, clean_up_on_signals, clean_up_on_signals_then, folder_of, same_file, sibling, stop,
    write_all_atomic, write_atomic, OutputFiles, Staged, MAX_NAME_BYTES, STOP_SECONDS, TEMP_MARK,
};
pub use panels::{scaled_to_height, side_by_side};
pub use raypatch_engine::pipeline_cache::{driver_cache_note, prepare_driver_cache};
pub use raypatch_engine::{
    AdapterChoice, MatmulKernel, OpTimes, Output, Outputs, PipelineCacheDir, PipelineCacheStatus, Precision, Region,
    RenderStats, Request,
};
#[cfg(not(target_family = "wasm"))]
pub use render::RenderPath;
pub use render::{Adapter, Engine, EngineOptions, InputView, Model, Rendered, Scene};

pub use raypatch_engine;
pub use raypatch_model;
