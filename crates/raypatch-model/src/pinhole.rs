//! A pinhole camera's rays, made by one algorithm that the host (here) and the GPU (`shaders/rays.wgsl`) run
//! alike, so that a render made from a camera's pose and intrinsics on the GPU sees the very rays the host
//! gives for it.
//!
//! The ray through pixel centre (row i, column j) is `R·[u_j, v_i, 1]` with `u_j = (j + 0.5 − cx) / fx` and
//! `v_i = (i + 0.5 − cy) / fy`: the sum of a column term `R·[u_j, 0, 0]` and a row term `R·[0, v_i, 1]` (plus
//! the camera centre for unit-depth points). The host computes the terms in float64, O(width + height) of them.
//! A pixel's ray is their sum, then (for a unit direction) its normalisation, in double-single arithmetic: each
//! value a pair of float32 (hi + lo, about 48 bits), exact sums and products by Knuth's and Dekker's
//! error-free transformations, an inverse square root started from an integer estimate rather than a built-in
//! whose rounding varies by GPU, and only float32 additions and multiplications, which Vulkan requires to be
//! correctly rounded. No fused multiply-add: a GPU's need not be fused (lavapipe's is not), and the shader
//! keeps its compiler from fusing or rewriting its sums. So the GPU's rays are bit-equal to these, and within
//! one float32 rounding of the float64 rays (a value lands on the other side of a rounding boundary about once
//! in a million).
//!
//! Why not float32 throughout: the official models' ray encoding multiplies a ray by up to 2^14·π, so a ray
//! off by one float32 rounding moves a render by about 1e-3. WGSL has no float64.

use crate::config::RayKind;

/// A pinhole camera's rays of one view: its column and row terms (see the module's documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct PinholeRays {
    pub kind: RayKind,
    /// `R·[u_j, 0, 0]` for each column j of the image.
    pub columns: Vec<[f64; 3]>,
    /// `R·[0, v_i, 1]` for each row i (plus the camera centre for [`RayKind::UnitDepthPoint`]).
    pub rows: Vec<[f64; 3]>,
}

/// Focal length of the MultiShapeNet cameras (metres), as in the official data loader.
pub const MSN_FOCAL_LENGTH: f64 = 0.035;
/// Sensor width of the MultiShapeNet cameras (metres), as in the official data loader.
pub const MSN_SENSOR_WIDTH: f64 = 0.032;

/// Pinhole intrinsics in pixels, for an image of `width` × `height`. A pixel (column `j`, row `i`) has its
/// centre at `(j + 0.5, i + 0.5)`; the principal point `(cx, cy)` is in the same coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Horizontal focal length in pixels.
    pub fx: f64,
    /// Vertical focal length in pixels.
    pub fy: f64,
    /// Principal point, column coordinate (pixels from the left edge).
    pub cx: f64,
    /// Principal point, row coordinate (pixels from the top edge).
    pub cy: f64,
}

impl Intrinsics {
    /// Square pixels and a centred principal point, from a focal length and sensor width in the same unit.
    pub fn from_sensor(focal_length: f64, sensor_width: f64, width: usize, height: usize) -> Intrinsics {
        let f = focal_length / sensor_width * width as f64;
        Intrinsics { width, height, fx: f, fy: f, cx: width as f64 / 2.0, cy: height as f64 / 2.0 }
    }

    /// The MultiShapeNet cameras: focal length 0.035, sensor width 0.032.
    pub fn msn(width: usize, height: usize) -> Intrinsics {
        Intrinsics::from_sensor(MSN_FOCAL_LENGTH, MSN_SENSOR_WIDTH, width, height)
    }
}

/// Floats a term takes in a GPU upload: hi (x, y, z, kind), then lo (x, y, z, 0); kind is
/// [`PinholeRays::gpu_kind`] (the rays' kind travels with the terms, which are made for it: the GPU makes a
/// camera's rays of the camera's kind, as the host does, whatever the model's).
pub const TERM_FLOATS: usize = 8;

/// Rays from which [`PinholeRays::write`] shares the work among the cores (below, the threads would cost more
/// than they save: a ray takes some 250 ns).
pub const PARALLEL_RAYS: usize = 1 << 14;

impl PinholeRays {
    /// The rays of `kind` of a camera at `position` with world-from-camera rotation `rotation` (its columns:
    /// the camera's x, y and z axes in the world) and intrinsics `pinhole`.
    pub fn new(kind: RayKind, pinhole: &Intrinsics, rotation: [[f64; 3]; 3], position: [f64; 3]) -> PinholeRays {
        let [x_axis, y_axis, z_axis] = rotation;
        let columns = (0..pinhole.width)
            .map(|j| {
                let u = (j as f64 + 0.5 - pinhole.cx) / pinhole.fx;
                x_axis.map(|c| c * u)
            })
            .collect();
        let centre = match kind {
            RayKind::UnitDirection => [0.0; 3],
            RayKind::UnitDepthPoint => position,
        };
        let rows = (0..pinhole.height)
            .map(|i| {
                let v = (i as f64 + 0.5 - pinhole.cy) / pinhole.fy;
                std::array::from_fn(|c| y_axis[c] * v + z_axis[c] + centre[c])
            })
            .collect();
        PinholeRays { kind, columns, rows }
    }

    pub fn width(&self) -> usize {
        self.columns.len()
    }

    pub fn height(&self) -> usize {
        self.rows.len()
    }

    /// The ray of pixel (row `i`, column `j`).
    pub fn ray(&self, i: usize, j: usize) -> [f32; 3] {
        let world = [0, 1, 2].map(|c| Df::split(self.columns[j][c]).add(Df::split(self.rows[i][c])));
        match self.kind {
            RayKind::UnitDepthPoint => world.map(Df::round),
            RayKind::UnitDirection => {
                let [x, y, z] = world;
                let inverse_norm = x.mul(x).add(y.mul(y)).add(z.mul(z)).inverse_sqrt();
                world.map(|w| w.mul(inverse_norm).round())
            }
        }
    }

    /// Writes every ray, row-major, 3 floats a ray, into `out`: a band of rows per core for large images.
    pub fn write(&self, out: &mut [f32]) {
        let (width, height) = (self.width(), self.height());
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        if threads == 1 || width * height < PARALLEL_RAYS {
            return self.write_rows(0..height, out);
        }
        let rows_each = height.div_ceil(threads);
        std::thread::scope(|scope| {
            for (band, values) in out.chunks_mut(rows_each * width * 3).enumerate() {
                scope.spawn(move || {
                    let first = band * rows_each;
                    self.write_rows(first..first + values.len() / (width * 3), values);
                });
            }
        });
    }

    /// Writes the rays of rows `rows` (all columns), 3 floats a ray, into `out`.
    pub fn write_rows(&self, rows: std::ops::Range<usize>, out: &mut [f32]) {
        let width = self.width();
        assert_eq!(out.len(), rows.len() * width * 3, "write_rows: room for {} rows of {width} rays", rows.len());
        for (i, row) in rows.zip(out.chunks_exact_mut(width * 3)) {
            for (j, ray) in row.chunks_exact_mut(3).enumerate() {
                ray.copy_from_slice(&self.ray(i, j));
            }
        }
    }

    /// Whether every ray comes out finite: every term is finite and small enough that no sum of two, or for
    /// a unit direction no squared norm split for a product, overflows float32 (terms under 1e37 and 1e15).
    pub fn is_finite(&self) -> bool {
        let bound = match self.kind {
            RayKind::UnitDirection => 1e15,
            RayKind::UnitDepthPoint => 1e37,
        };
        self.columns.iter().chain(&self.rows).flatten().all(|v| v.abs() < bound)
    }

    /// The terms of columns `columns` then rows `rows` as the GPU reads them (`shaders/rays.wgsl`), each
    /// [`TERM_FLOATS`] floats: hi (x, y, z, kind), then lo (x, y, z, 0), kind [`gpu_kind`](Self::gpu_kind).
    pub fn gpu_terms(
        &self,
        columns: std::ops::Range<usize>,
        rows: std::ops::Range<usize>,
    ) -> impl Iterator<Item = [f32; TERM_FLOATS]> + '_ {
        let kind = self.gpu_kind();
        self.columns[columns].iter().chain(&self.rows[rows]).map(move |term| {
            let [x, y, z] = term.map(Df::split);
            [x.hi, y.hi, z.hi, kind, x.lo, y.lo, z.lo, 0.0]
        })
    }

    /// The rays' kind as every GPU term carries it: 0 for unit directions (normalised), 1 for unit-depth
    /// points. The terms are made for this kind (a unit-depth point's row terms hold the camera centre), so
    /// the GPU takes it from them, never from the model: a camera's rays are of its own kind on the GPU as on
    /// the host ([`ray`](Self::ray)).
    pub fn gpu_kind(&self) -> f32 {
        gpu_kind_of(self.kind)
    }
}

/// A ray kind as the GPU terms carry it ([`PinholeRays::gpu_kind`]; `shaders/rays.wgsl` names them `RAY_KIND_*`).
pub fn gpu_kind_of(kind: RayKind) -> f32 {
    match kind {
        RayKind::UnitDirection => 0.0,
        RayKind::UnitDepthPoint => 1.0,
    }
}

/// A double-single value: hi + lo, |lo| at most half an ulp of hi. The operations are those of
/// `shaders/rays.wgsl`, step for step.
#[derive(Clone, Copy, Debug)]
struct Df {
    hi: f32,
    lo: f32,
}

/// s + e = a + b exactly (Knuth), s the rounded sum.
fn two_sum(a: f32, b: f32) -> Df {
    let s = a + b;
    let bb = s - a;
    Df { hi: s, lo: (a - (s - bb)) + (b - bb) }
}

/// s + e = a + b exactly for |a| ≥ |b| (or a = 0).
fn quick_two_sum(a: f32, b: f32) -> Df {
    let s = a + b;
    Df { hi: s, lo: b - (s - a) }
}

/// hi + lo = a, each with at most 12 significant bits (Dekker), so that products of halves are exact.
fn split(a: f32) -> Df {
    let t = 4097.0 * a;
    let hi = t - (t - a);
    Df { hi, lo: a - hi }
}

/// p + e = a·b exactly (Dekker's, not a fused multiply-add: a GPU's fma need not be fused).
fn two_prod(a: f32, b: f32) -> Df {
    let p = a * b;
    let (x, y) = (split(a), split(b));
    Df { hi: p, lo: (((x.hi * y.hi - p) + x.hi * y.lo) + x.lo * y.hi) + x.lo * y.lo }
}

impl Df {
    fn split(x: f64) -> Df {
        let hi = x as f32;
        Df { hi, lo: (x - f64::from(hi)) as f32 }
    }

    fn add(self, b: Df) -> Df {
        let s = two_sum(self.hi, b.hi);
        let t = two_sum(self.lo, b.lo);
        let u = quick_two_sum(s.hi, s.lo + t.hi);
        quick_two_sum(u.hi, u.lo + t.lo)
    }

    fn mul(self, b: Df) -> Df {
        let p = two_prod(self.hi, b.hi);
        quick_two_sum(p.hi, (self.hi * b.lo + self.lo * b.hi) + p.lo)
    }

    /// 1/√x for x ≥ 1 (a squared norm of R·[u, v, 1]): an integer estimate, three float32 Newton steps, two
    /// double-single ones.
    fn inverse_sqrt(self) -> Df {
        let x = self.hi;
        let half = 0.5 * x;
        let mut r = f32::from_bits(0x5f37_59df - (x.to_bits() >> 1));
        for _ in 0..3 {
            r *= 1.5 - (half * r) * r;
        }
        let mut r = Df { hi: r, lo: 0.0 };
        for _ in 0..2 {
            // r + r·(1 − x·r²)/2
            let e = Df { hi: 1.0, lo: 0.0 }.add(self.mul(r.mul(r)).neg());
            r = r.add(r.mul(Df { hi: 0.5 * e.hi, lo: 0.5 * e.lo }));
        }
        r
    }

    fn neg(self) -> Df {
        Df { hi: -self.hi, lo: -self.lo }
    }

    /// The float32 nearest hi + lo.
    fn round(self) -> f32 {
        self.hi + self.lo
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rotation from Euler angles (radians), as columns.
    fn rotation(a: f64, b: f64, c: f64) -> [[f64; 3]; 3] {
        let (sa, ca, sb, cb, sc, cc) = (a.sin(), a.cos(), b.sin(), b.cos(), c.sin(), c.cos());
        [
            [ca * cb, sa * cb, -sb],
            [ca * sb * sc - sa * cc, sa * sb * sc + ca * cc, cb * sc],
            [ca * sb * cc + sa * sc, sa * sb * cc - ca * sc, cb * cc],
        ]
    }

    /// The float64 ray of pixel (i, j), rounded once to float32.
    fn float64_ray(
        kind: RayKind,
        k: &Intrinsics,
        r: [[f64; 3]; 3],
        position: [f64; 3],
        i: usize,
        j: usize,
    ) -> [f32; 3] {
        let (u, v) = ((j as f64 + 0.5 - k.cx) / k.fx, (i as f64 + 0.5 - k.cy) / k.fy);
        let w: [f64; 3] = std::array::from_fn(|c| r[0][c] * u + r[1][c] * v + r[2][c]);
        let n = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
        std::array::from_fn(|c| match kind {
            RayKind::UnitDirection => (w[c] / n) as f32,
            RayKind::UnitDepthPoint => (position[c] + w[c]) as f32,
        })
    }

    #[test]
    fn rays_are_the_float64_rays_rounded_once_but_for_rare_ties() {
        let cameras = [
            (
                Intrinsics { width: 160, height: 120, fx: 175.0, fy: 175.0, cx: 80.0, cy: 60.0 },
                rotation(0.3, -1.1, 2.0),
            ),
            (Intrinsics { width: 97, height: 61, fx: 13.7, fy: 11.2, cx: 40.3, cy: 33.9 }, rotation(-2.5, 0.7, 0.01)),
            (Intrinsics { width: 64, height: 64, fx: 0.05, fy: 0.05, cx: 32.0, cy: 32.0 }, rotation(1.0, 1.0, 1.0)),
        ];
        let position = [0.37, -2.9, 5.125];
        let (mut values, mut off, mut worst) = (0usize, 0usize, 0.0f64);
        for kind in [RayKind::UnitDirection, RayKind::UnitDepthPoint] {
            for (k, r) in &cameras {
                let rays = PinholeRays::new(kind, k, *r, position);
                for i in 0..k.height {
                    for j in 0..k.width {
                        let (got, want) = (rays.ray(i, j), float64_ray(kind, k, *r, position, i, j));
                        for c in 0..3 {
                            values += 1;
                            if got[c] != want[c] {
                                off += 1;
                                let ulp = f64::from(want[c].abs()) * f64::from(f32::EPSILON);
                                worst = worst.max(f64::from(got[c] - want[c]).abs() / ulp);
                            }
                        }
                    }
                }
            }
        }
        assert!(values > 100_000);
        assert!(off * 100_000 <= values, "{off} of {values} values differ from the float64 rays rounded once");
        assert!(worst <= 1.0, "a value is {worst} ulp from the float64 ray's");
    }

    #[test]
    fn terms_split_into_hi_and_lo_for_the_gpu() {
        let x = 1.0 / 3.0;
        let rays = PinholeRays { kind: RayKind::UnitDirection, columns: vec![[x, 2.0, 0.0]], rows: vec![] };
        let [hi, y, _, kind, lo, .., pad] = rays.gpu_terms(0..1, 0..0).next().unwrap();
        assert!((f64::from(hi) + f64::from(lo) - x).abs() < 1e-15);
        assert_eq!((y, kind, pad), (2.0, 0.0, 0.0));
        let points = PinholeRays { kind: RayKind::UnitDepthPoint, ..rays };
        assert!(points.gpu_terms(0..1, 0..0).all(|term| term[3] == 1.0), "a unit-depth point's terms say so");
    }

    #[test]
    fn rays_that_would_overflow_float32_are_not_finite() {
        let rays = |kind, x| PinholeRays { kind, columns: vec![[x, 0.0, 0.0]], rows: vec![[0.0, 0.0, 1.0]] };
        assert!(rays(RayKind::UnitDepthPoint, 1e30).is_finite());
        assert!(!rays(RayKind::UnitDepthPoint, 1e38).is_finite());
        assert!(!rays(RayKind::UnitDirection, 1e30).is_finite());
        assert!(!rays(RayKind::UnitDirection, f64::NAN).is_finite());
    }
}
