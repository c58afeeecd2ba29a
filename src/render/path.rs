//! A sequence of cameras rendered a batch at a time ([`Scene::render_path`](super::Scene::render_path)), each
//! batch's targets made as the engine takes them, one batch kept in flight.

use raypatch_model::pinhole::PinholeRays;
use raypatch_model::{RayKind, TargetRays};

use super::Rendered;
use crate::camera::Camera;
use crate::error::{Error, Result};

/// `cameras` (one size) as one batch of the engine's render targets, with rays of `kind`: pinhole cameras as
/// such (their rays made on the GPU), else every camera's rays as values.
fn targets_of(cameras: &[Camera], kind: RayKind) -> raypatch_model::TargetViews {
    let (width, height) = cameras[0].ray_grid_size();
    let pinholes: Option<Vec<PinholeRays>> = cameras.iter().map(|c| c.pinhole_rays(kind)).collect();
    let rays = match pinholes {
        Some(pinholes) => TargetRays::Pinhole(pinholes),
        None => {
            let per_view = width * height * 3;
            let mut rays = vec![0.0; per_view * cameras.len()];
            for (camera, rays) in cameras.iter().zip(rays.chunks_exact_mut(per_view)) {
                camera.write_rays(kind, rays);
            }
            TargetRays::Given(rays)
        }
    };
    raypatch_model::TargetViews {
        count: cameras.len(),
        camera_pos: cameras.iter().flat_map(|c| c.position().as_vec3().to_array()).collect(),
        rays,
        rays_height: height,
        rays_width: width,
        declared_size: Some((cameras[0].height(), cameras[0].width())),
        images: None,
        masks: None,
    }
}

/// A path's batches of render targets, made as the engine takes them: `batch` cameras each, the last filled
/// up with its last camera when the path has more than one batch (so that every batch has one plan).
pub(super) struct Batches<'s> {
    pub(super) cameras: &'s [Camera],
    /// Cameras rendered: those before the first that cannot be.
    pub(super) end: usize,
    pub(super) batch: usize,
    pub(super) kind: RayKind,
    pub(super) next: usize,
}

impl Iterator for Batches<'_> {
    type Item = raypatch_model::TargetViews;

    fn next(&mut self) -> Option<raypatch_model::TargetViews> {
        if self.next >= self.end {
            return None;
        }
        let stop = (self.next + self.batch).min(self.end);
        let real = &self.cameras[self.next..stop];
        self.next = stop;
        if real.len() == self.batch || self.cameras.len() <= self.batch {
            return Some(targets_of(real, self.kind));
        }
        let mut padded = real.to_vec();
        padded.resize(self.batch, real[real.len() - 1].clone());
        Some(targets_of(&padded, self.kind))
    }
}

/// The frames of [`Scene::render_path`], in order; an error ends the path.
pub struct RenderPath<'s> {
    pub(super) renders: raypatch_engine::Renders<'s, Batches<'s>>,
    /// The cameras rendered (before the first that cannot be).
    pub(super) cameras: &'s [Camera],
    pub(super) batch: usize,
    /// Frames handed out or waiting in `ready`.
    pub(super) next: usize,
    /// The rest of the current batch, last frame first.
    pub(super) ready: Vec<Rendered>,
    /// Why a camera of the batch after `cameras` cannot be rendered, handed out after their frames.
    pub(super) failure: Option<Error>,
}

impl Iterator for RenderPath<'_> {
    type Item = Result<Rendered>;

    fn next(&mut self) -> Option<Result<Rendered>> {
        if self.ready.is_empty() && self.next < self.cameras.len() {
            match self.renders.next().expect("a batch per camera left") {
                Ok(frames) => {
                    let real = self.batch.min(self.cameras.len() - self.next);
                    self.next += real;
                    self.ready = (frames.into_iter().take(real))
                        .map(|f| Rendered { region: f.region, outputs: f.outputs })
                        .rev()
                        .collect();
                }
                Err(e) => {
                    self.next = self.cameras.len();
                    self.failure = None;
                    return Some(Err(e.into()));
                }
            }
        }
        match self.ready.pop() {
            Some(frame) => Some(Ok(frame)),
            None => self.failure.take().map(Err),
        }
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let left = self.ready.len() + self.cameras.len() - self.next + usize::from(self.failure.is_some());
        (left, Some(left))
    }
}
