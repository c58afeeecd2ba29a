//! What each kind of ray looks like ([`RayKind`]), checked for rays given as such (a scene file's, an API
//! caller's): every one of them, with a message saying what they look like instead.

use crate::config::RayKind;

/// How far a ray may be from its kind ([`check_ray_kind`]): a unit direction's length from 1 (patch rays,
/// resized from unit rays without renormalising, stay within 1e-3 of it), a unit-depth point's depth along the
/// camera's forward axis from 1. Rays of the other kind are far outside, except through a camera whose field of
/// view is under a few degrees, where the two kinds differ by less than this.
pub const RAY_KIND_TOLERANCE: f64 = 0.01;

/// Checks one camera's rays against the kind a model takes: `width` × `height` rays, row-major, `ray(i)` the
/// i-th, of a camera centred at `position`. On failure, the reason in one line: the first ray at fault, and
/// what the rays look like when they are of the other kind.
///
/// - [`RayKind::UnitDirection`]: every ray's length is within [`RAY_KIND_TOLERANCE`] of 1.
/// - [`RayKind::UnitDepthPoint`]: each point's offset from the camera centre, o = R·K⁻¹p, has depth 1 along
///   the camera's forward axis f (a unit vector): f·o = 1, so the offsets lie on one plane at distance 1 from
///   the centre. Their lengths are 1 only on the optical axis (1/cos of the angle to it elsewhere), so a length
///   check would refuse them. f is not in the file: o = a + u·b + v·c is affine in the pixel (u, v), so the
///   grid's two diagonals span b and c, and f is the unit normal b × c, oriented towards the points. Every
///   offset's f·o must be within the tolerance of 1. A grid of one row or one column spans no plane: there each
///   offset need only be at least 1 long (1 − the tolerance).
///
/// The tolerance grows by 1e-6 times the largest coordinate of the camera centre, for float32 rounding of
/// points far from the origin.
pub fn check_ray_kind(
    kind: RayKind,
    position: [f32; 3],
    width: usize,
    height: usize,
    ray: impl Fn(usize) -> [f32; 3],
) -> Result<(), String> {
    let count = width * height;
    let at = |i: usize| ray(i).map(f64::from);
    let centre = position.map(f64::from);
    let tolerance = RAY_KIND_TOLERANCE + 1e-6 * centre.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let shown = |i: usize| {
        let [x, y, z] = ray(i);
        format!("[{x}, {y}, {z}]")
    };
    let unit_lengths = || (0..count).all(|i| (norm(at(i)) - 1.0).abs() <= tolerance);
    match kind {
        RayKind::UnitDirection => {
            let Some(i) = (0..count).find(|&i| (norm(at(i)) - 1.0).abs() > tolerance) else {
                return Ok(());
            };
            let looks = if unit_depth_fault(centre, width, height, &at, tolerance).is_none() {
                " (these look like unit-depth points, DeFiNe's kind: camera centre + R·K⁻¹[u+0.5, v+0.5, 1])"
            } else {
                ""
            };
            Err(format!(
                "ray {i} is {} of length {:.4}; this model takes {}{looks}",
                shown(i),
                norm(at(i)),
                kind.describe()
            ))
        }
        RayKind::UnitDepthPoint => {
            let Some((i, fault)) = unit_depth_fault(centre, width, height, &at, tolerance) else {
                return Ok(());
            };
            let looks =
                if unit_lengths() { " (these look like unit ray directions, SRT's and OSRT's kind)" } else { "" };
            Err(format!("ray {i} is {} {fault}; this model takes {}{looks}", shown(i), kind.describe()))
        }
    }
}

fn norm(v: [f64; 3]) -> f64 {
    dot(v, v).sqrt()
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// The first ray that is not a unit-depth point of a camera at `centre` (see [`check_ray_kind`]) and what is
/// wrong with it; `None` when all are.
fn unit_depth_fault(
    centre: [f64; 3],
    width: usize,
    height: usize,
    at: &dyn Fn(usize) -> [f64; 3],
    tolerance: f64,
) -> Option<(usize, String)> {
    let offset = |i: usize| sub(at(i), centre);
    let count = width * height;
    if width < 2 || height < 2 {
        let i = (0..count).find(|&i| norm(offset(i)) < 1.0 - tolerance)?;
        return Some((i, format!("at {:.4} from the camera centre, nearer than depth 1", norm(offset(i)))));
    }
    let corner = |x: usize, y: usize| offset(y * width + x);
    let (top_left, bottom_right) = (corner(0, 0), corner(width - 1, height - 1));
    let (top_right, bottom_left) = (corner(width - 1, 0), corner(0, height - 1));
    let (d1, d2) = (sub(bottom_right, top_left), sub(top_right, bottom_left));
    let cross = [d1[1] * d2[2] - d1[2] * d2[1], d1[2] * d2[0] - d1[0] * d2[2], d1[0] * d2[1] - d1[1] * d2[0]];
    let length = norm(cross);
    if length.is_nan() || length <= 1e-9 * norm(d1) * norm(d2) {
        return Some((0, format!("and the {width}x{height} grid's points lie on one line, not on an image plane")));
    }
    let side =
        dot(cross, [top_left[0] + bottom_right[0], top_left[1] + bottom_right[1], top_left[2] + bottom_right[2]]);
    let forward = cross.map(|c| c / length * side.signum());
    let i = (0..count).find(|&i| (dot(forward, offset(i)) - 1.0).abs() > tolerance)?;
    Some((
        i,
        format!(
            "at depth {:.4} along the camera's forward axis (the normal of the plane of the grid's corners), expected 1",
            dot(forward, offset(i))
        ),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rays of a pinhole camera (focal `f` pixels, centred principal point) at `centre`, looking along
    /// `forward` with image right `right`, of `kind`, `width` × `height`.
    fn pinhole(
        kind: RayKind,
        centre: [f64; 3],
        right: [f64; 3],
        forward: [f64; 3],
        f: f64,
        (width, height): (usize, usize),
    ) -> Vec<[f32; 3]> {
        let down = [
            forward[1] * right[2] - forward[2] * right[1],
            forward[2] * right[0] - forward[0] * right[2],
            forward[0] * right[1] - forward[1] * right[0],
        ];
        let mut rays = Vec::new();
        for v in 0..height {
            for u in 0..width {
                let (x, y) = ((u as f64 + 0.5 - width as f64 / 2.0) / f, (v as f64 + 0.5 - height as f64 / 2.0) / f);
                let o: [f64; 3] = std::array::from_fn(|i| x * right[i] + y * down[i] + forward[i]);
                rays.push(match kind {
                    RayKind::UnitDirection => o.map(|c| (c / norm(o)) as f32),
                    RayKind::UnitDepthPoint => std::array::from_fn(|i| (centre[i] + o[i]) as f32),
                });
            }
        }
        rays
    }

    fn check(kind: RayKind, centre: [f64; 3], rays: &[[f32; 3]], size: (usize, usize)) -> Result<(), String> {
        check_ray_kind(kind, centre.map(|c| c as f32), size.0, size.1, |i| rays[i])
    }

    #[test]
    fn each_kind_passes_its_own_check_and_fails_the_other() {
        let s = std::f64::consts::FRAC_1_SQRT_2;
        // A tilted camera far from the origin with a wide view (ScanNet-like: 640x480, focal 577 scaled).
        let (centre, right, forward) = ([120.0, -35.0, 2.5], [s, s, 0.0], [0.5, -0.5, -s]);
        for size in [(64, 48), (2, 2), (5, 3)] {
            let f = 0.9 * size.0 as f64;
            let directions = pinhole(RayKind::UnitDirection, centre, right, forward, f, size);
            let points = pinhole(RayKind::UnitDepthPoint, centre, right, forward, f, size);
            assert_eq!(check(RayKind::UnitDirection, centre, &directions, size), Ok(()));
            assert_eq!(check(RayKind::UnitDepthPoint, centre, &points, size), Ok(()));
            let e = check(RayKind::UnitDirection, centre, &points, size).unwrap_err();
            assert!(
                e.contains("this model takes unit ray directions") && e.contains("look like unit-depth points"),
                "{e}"
            );
            let e = check(RayKind::UnitDepthPoint, centre, &directions, size).unwrap_err();
            assert!(
                e.contains("this model takes unit-depth points") && e.contains("look like unit ray directions"),
                "{e}"
            );
        }
        // Unit-depth points are not unit length off the optical axis: 1/cos of the angle to it.
        let size = (64, 48);
        let points = pinhole(RayKind::UnitDepthPoint, centre, right, forward, 57.6, size);
        let corner = norm(sub(points[0].map(f64::from), centre));
        assert!(corner > 1.2, "{corner}");
    }

    #[test]
    fn wrong_depths_scales_and_grids_are_named() {
        let (centre, right, forward) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]);
        let size = (8, 6);
        let mut points = pinhole(RayKind::UnitDepthPoint, centre, right, forward, 6.0, size);
        // One point off the image plane.
        points[13][2] = 1.2;
        let e = check(RayKind::UnitDepthPoint, centre, &points, size).unwrap_err();
        assert!(e.starts_with("ray 13 is") && e.contains("at depth 1.2") && e.contains("expected 1"), "{e}");
        assert!(!e.contains("look like"), "{e}");
        // Points at depth 2 (a scaled K): every depth is 2.
        let doubled: Vec<[f32; 3]> = pinhole(RayKind::UnitDepthPoint, centre, right, forward, 6.0, size)
            .iter()
            .map(|p| p.map(|c| 2.0 * c))
            .collect();
        let e = check(RayKind::UnitDepthPoint, centre, &doubled, size).unwrap_err();
        assert!(e.starts_with("ray 0 is") && e.contains("at depth 2"), "{e}");
        // All rays the same point: no image plane.
        let same = vec![[0.0, 0.0, 1.0f32]; 48];
        let e = check(RayKind::UnitDepthPoint, centre, &same, size).unwrap_err();
        assert!(e.contains("on one line"), "{e}");
        // Unnormalised directions.
        let long: Vec<[f32; 3]> = pinhole(RayKind::UnitDirection, centre, right, forward, 6.0, size)
            .iter()
            .map(|p| p.map(|c| 1.5 * c))
            .collect();
        let e = check(RayKind::UnitDirection, centre, &long, size).unwrap_err();
        assert!(e.contains("of length 1.5") && e.contains("this model takes unit ray directions"), "{e}");
        // One row: no plane to fit; a point nearer than depth 1 is still refused.
        let row = pinhole(RayKind::UnitDepthPoint, centre, right, forward, 6.0, (8, 1));
        assert_eq!(check(RayKind::UnitDepthPoint, centre, &row, (8, 1)), Ok(()));
        let mut near = row.clone();
        near[3] = [0.0, 0.0, 0.5];
        let e = check(RayKind::UnitDepthPoint, centre, &near, (8, 1)).unwrap_err();
        assert!(e.starts_with("ray 3 is") && e.contains("nearer than depth 1"), "{e}");
    }
}
