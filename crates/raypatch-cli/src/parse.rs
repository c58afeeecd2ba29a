//! The values of render-frame's flags that clap cannot check alone: counts, frame rates, output lists, depth
//! ranges and regions, each refused with what was expected.

use raypatch::{Output, Outputs, Region};

/// Most renders one run makes (turntable frames, repeats): each takes at least milliseconds of GPU time.
pub const MAX_RENDERS: usize = 100_000;

/// A count of renders, 0 to [`MAX_RENDERS`].
pub fn parse_count(text: &str) -> Result<usize, String> {
    match text.trim().parse::<usize>() {
        Ok(n) if n <= MAX_RENDERS => Ok(n),
        _ => Err(format!("expected a whole number from 0 to {MAX_RENDERS}")),
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
        None => Err(format!("unknown output {name:?}: expected a comma-separated list of {}", names())),
    })
}

/// `MIN,MAX` in metres, 0 <= MIN < MAX.
pub fn parse_depth_range(text: &str) -> Result<(f32, f32), String> {
    let bad = || format!("{text:?} is not MIN,MAX (two depths in metres, 0 <= MIN < MAX)");
    let parts: Vec<f32> =
        text.split(',').map(|p| p.trim().parse::<f32>()).collect::<Result<_, _>>().map_err(|_| bad())?;
    match parts[..] {
        [lo, hi] if lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo < hi => Ok((lo, hi)),
        _ => Err(bad()),
    }
}

pub fn parse_region(text: &str) -> Result<Region, String> {
    let parts: Vec<usize> = text
        .split(',')
        .map(|p| p.trim().parse::<usize>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("{text:?} is not X,Y,W,H (four non-negative integers)"))?;
    match parts[..] {
        [x, y, width, height] if width > 0 && height > 0 => Ok(Region { x, y, width, height }),
        [_, _, _, _] => Err(format!("{text:?}: width and height must be positive")),
        _ => Err(format!("{text:?} is not X,Y,W,H (four non-negative integers)")),
    }
}
