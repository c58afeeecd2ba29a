//! --panels: each frame of --out laid out side by side with labels: the colour, the depth in the turbo map
//! with one range for the whole run, the object masks in the fixed palette, the first input view.

use anyhow::{Context, Result};
use raypatch::{Image, Output, Rendered};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Panel {
    Rgb,
    Depth,
    Segmentation,
    Input,
}

impl Panel {
    pub const ALL: [Panel; 4] = [Panel::Rgb, Panel::Depth, Panel::Segmentation, Panel::Input];

    pub fn name(self) -> &'static str {
        match self {
            Panel::Rgb => "rgb",
            Panel::Depth => "depth",
            Panel::Segmentation => "segmentation",
            Panel::Input => "input",
        }
    }

    /// The output this panel shows, if it shows one.
    pub fn output(self) -> Option<Output> {
        match self {
            Panel::Rgb => Some(Output::Rgb),
            Panel::Depth => Some(Output::Depth),
            Panel::Segmentation => Some(Output::Segmentation),
            Panel::Input => None,
        }
    }
}

/// What --out shows of one rendered frame: its colour, or its panels side by side. `depth_range` is the one
/// range of every depth panel; `input` the first input view.
pub fn frame_picture(
    panels: &[Panel],
    rendered: &Rendered,
    depth_range: Option<(f32, f32)>,
    input: &Image,
) -> Result<Image> {
    let (width, height) = (rendered.region.width, rendered.region.height);
    if panels.is_empty() {
        return Ok(rendered.rgb().expect("rgb is rendered for --out"));
    }
    let pictures = (panels.iter())
        .map(|panel| {
            let picture = match panel {
                Panel::Rgb => rendered.rgb().expect("the rgb panel's output was requested"),
                Panel::Depth => {
                    let depth = rendered.depth().expect("the depth panel's output was requested");
                    Image::from_depth(width, height, depth, depth_range)?
                }
                Panel::Segmentation => {
                    let (weights, slots) =
                        rendered.segmentation().expect("the segmentation panel's output was requested");
                    Image::from_segmentation(width, height, weights, slots)?
                }
                Panel::Input => raypatch::scaled_to_height(input, height)?,
            };
            Ok((panel.name(), picture))
        })
        .collect::<raypatch::Result<Vec<_>>>()
        .context("--panels")?;
    let refs: Vec<(&str, &Image)> = pictures.iter().map(|(name, p)| (*name, p)).collect();
    raypatch::side_by_side(&refs).context("--panels")
}

/// The depth range over every valid pixel of `depths`, folded into `range`.
pub fn widen_range(range: Option<(f32, f32)>, depth: &[f32]) -> Option<(f32, f32)> {
    depth.iter().copied().filter(|d| d.is_finite() && *d > 0.0).fold(range, |r, d| match r {
        None => Some((d, d)),
        Some((lo, hi)) => Some((lo.min(d), hi.max(d))),
    })
}
