//! The values of render-frame's flags that clap cannot check alone: counts, frame rates, output lists, depth
//! ranges, regions, motions and MP4 encodings, each refused with what was expected.

use raypatch::raypatch_model::error::Quoted;
use raypatch::{Output, Outputs, Region};

use crate::panels::Panel;

/// A flag's text as its error quotes it: in quotes, a bounded excerpt of a long one.
pub fn quote(text: &str) -> String {
    format!("{:?}", Quoted(text))
}

/// A count of renders (frames, repeats), 0 to [`raypatch::MAX_PATH_FRAMES`].
pub fn parse_count(text: &str) -> Result<usize, String> {
    let most = raypatch::MAX_PATH_FRAMES;
    match text.trim().parse::<usize>() {
        Ok(n) if n <= most => Ok(n),
        _ => Err(format!("expected a whole number from 0 to {most}")),
    }
}

pub fn parse_fps(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(f) if f.is_finite() && (1.0..=100.0).contains(&f) => Ok(f),
        _ => Err("expected frames per second, 1 to 100 (GIF delays are hundredths of a second)".into()),
    }
}

pub fn parse_outputs(text: &str) -> Result<Outputs, String> {
    let names = || Output::ALL.iter().map(|o| o.name()).collect::<Vec<_>>().join(", ");
    text.split(',').try_fold(Outputs::NONE, |set, name| match Output::from_name(name.trim()) {
        Some(output) => Ok(set.with(output)),
        None => Err(format!("unknown output {}: expected a comma-separated list of {}", quote(name), names())),
    })
}

/// `MIN,MAX` in metres, 0 <= MIN < MAX.
pub fn parse_depth_range(text: &str) -> Result<(f32, f32), String> {
    let quoted = quote(text);
    let bad = || format!("{quoted} is not MIN,MAX (two depths in metres, 0 <= MIN < MAX)");
    let parts: Vec<f32> =
        text.split(',').map(|p| p.trim().parse::<f32>()).collect::<Result<_, _>>().map_err(|_| bad())?;
    match parts[..] {
        [lo, hi] if lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo < hi => Ok((lo, hi)),
        _ => Err(bad()),
    }
}

pub fn parse_region(text: &str) -> Result<Region, String> {
    let quoted = quote(text);
    let parts: Vec<usize> = text
        .split(',')
        .map(|p| p.trim().parse::<usize>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("{quoted} is not X,Y,W,H (four non-negative integers)"))?;
    match parts[..] {
        [x, y, width, height] if width > 0 && height > 0 => Ok(Region { x, y, width, height }),
        [_, _, _, _] => Err(format!("{quoted}: width and height must be positive")),
        _ => Err(format!("{quoted} is not X,Y,W,H (four non-negative integers)")),
    }
}

/// `WxH` in pixels, each side 1 to [`raypatch::MAX_IMAGE_SIDE`], at most [`raypatch::MAX_IMAGE_PIXELS`] in all.
pub fn parse_size(text: &str) -> Result<(usize, usize), String> {
    let quoted = quote(text);
    let bad = || format!("{quoted} is not WxH (two whole numbers of pixels, e.g. 160x120)");
    let (w, h) = text.trim().split_once(['x', 'X']).ok_or_else(bad)?;
    let (w, h) = (w.trim().parse::<usize>().map_err(|_| bad())?, h.trim().parse::<usize>().map_err(|_| bad())?);
    raypatch::check_image_size(w, h).map_err(|e| format!("{quoted}: {e}"))?;
    Ok((w, h))
}

pub fn parse_motion(text: &str) -> Result<raypatch::Motion, String> {
    let quoted = quote(text);
    raypatch::Motion::from_name(text.trim()).ok_or_else(|| {
        let names: Vec<&str> = raypatch::Motion::ALL.iter().map(|m| m.name()).collect();
        format!("unknown motion {quoted}: expected one of {}", names.join(", "))
    })
}

pub fn parse_mp4_mode(text: &str) -> Result<crate::video::Mp4Mode, String> {
    let quoted = quote(text);
    use crate::video::Mp4Mode;
    Mp4Mode::from_name(text.trim()).ok_or_else(|| {
        let names: Vec<&str> = Mp4Mode::ALL.iter().map(|m| m.name()).collect();
        format!("unknown MP4 encoding {quoted}: expected one of {}", names.join(", "))
    })
}

/// `X,Y,Z`: three finite numbers.
pub fn parse_point(text: &str) -> Result<glam::DVec3, String> {
    let quoted = quote(text);
    let parts: Vec<f64> = text.split(',').filter_map(|p| p.trim().parse::<f64>().ok()).collect();
    match parts[..] {
        [x, y, z] if text.split(',').count() == 3 && parts.iter().all(|v| v.is_finite()) => {
            Ok(glam::DVec3::new(x, y, z))
        }
        _ => Err(format!("{quoted} is not X,Y,Z (three finite numbers)")),
    }
}

/// A world axis: x, y, z, -x, -y or -z.
pub fn parse_up(text: &str) -> Result<glam::DVec3, String> {
    let quoted = quote(text);
    let axis = match text.trim().trim_start_matches('+') {
        "x" => glam::DVec3::X,
        "y" => glam::DVec3::Y,
        "z" => glam::DVec3::Z,
        "-x" => -glam::DVec3::X,
        "-y" => -glam::DVec3::Y,
        "-z" => -glam::DVec3::Z,
        _ => return Err(format!("{quoted}: expected an axis: x, y, z, -x, -y or -z")),
    };
    Ok(axis)
}

/// A number for --fov and --elevation (whose ranges `raypatch::input` and `raypatch::motion_path` check).
pub fn parse_degrees(text: &str) -> Result<f64, String> {
    text.trim().parse::<f64>().map_err(|_| format!("{}: expected a number of degrees", quote(text)))
}

/// A finite, positive --radius.
pub fn parse_radius(text: &str) -> Result<f64, String> {
    let quoted = quote(text);
    match text.trim().parse::<f64>() {
        Ok(r) if r.is_finite() && r > 0.0 => Ok(r),
        _ => Err(format!("{quoted}: expected a positive, finite distance")),
    }
}

pub fn parse_panels(text: &str) -> Result<Vec<Panel>, String> {
    let mut panels = Vec::new();
    for name in text.split(',').map(str::trim) {
        let panel = Panel::ALL.into_iter().find(|p| p.name() == name).ok_or_else(|| {
            let names: Vec<&str> = Panel::ALL.iter().map(|p| p.name()).collect();
            format!("unknown panel {}: expected a comma-separated list of {}", quote(name), names.join(", "))
        })?;
        if panels.contains(&panel) {
            return Err(format!("{name} is listed twice"));
        }
        panels.push(panel);
    }
    Ok(panels)
}
