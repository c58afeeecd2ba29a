//! RGB images in f32, and pictures of a render's other outputs: segmentation masks and colour-mapped depth with
//! a legend.

use std::path::Path;

use crate::error::{Error, Result};
use crate::font;
#[cfg(not(target_family = "wasm"))]
use crate::output::write_atomic;
use crate::Region;

/// Longest image side accepted, in pixels: images are checked before they are decoded or rendered.
pub const MAX_IMAGE_SIDE: usize = 16384;
/// Most pixels in one image (4096 x 4096): 200 MB as f32 RGB, beyond what one GPU buffer of the encoder or
/// the decoder holds on most adapters.
pub const MAX_IMAGE_PIXELS: usize = 1 << 24;
/// Largest PNG file read.
pub(crate) const MAX_PNG_BYTES: u64 = 1 << 30;

/// Checks an image size against [`MAX_IMAGE_SIDE`] and [`MAX_IMAGE_PIXELS`]; the reason, width x height.
pub fn check_image_size(width: usize, height: usize) -> std::result::Result<(), String> {
    if width == 0 || height == 0 {
        return Err(format!("image size {width}x{height} (width x height) is empty"));
    }
    if width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE || width.saturating_mul(height) > MAX_IMAGE_PIXELS {
        return Err(format!(
            "image size {width}x{height} (width x height) is larger than raypatch accepts \
             ({MAX_IMAGE_SIDE} pixels a side, {MAX_IMAGE_PIXELS} pixels in all)"
        ));
    }
    Ok(())
}

/// Whether a depth value is one: finite and positive (ground truth holds 0 where it has none).
fn has_depth(d: f32) -> bool {
    d.is_finite() && d > 0.0
}

/// Google's turbo colour map (Mikhailov, 2019) at 17 evenly spaced stops, 8-bit, from matplotlib's table;
/// linear in between (within 8/255 of the full table).
const TURBO: [[u8; 3]; 17] = [
    [48, 18, 59],
    [64, 64, 162],
    [70, 107, 227],
    [66, 148, 255],
    [40, 188, 235],
    [24, 221, 194],
    [50, 242, 152],
    [109, 254, 98],
    [164, 252, 60],
    [205, 236, 52],
    [238, 207, 58],
    [253, 172, 52],
    [251, 126, 33],
    [235, 80, 14],
    [208, 47, 5],
    [169, 22, 1],
    [122, 4, 3],
];

/// Turbo at `t` in [0, 1]: dark blue at 0, dark red at 1.
fn turbo(t: f32) -> [f32; 3] {
    let x = t.clamp(0.0, 1.0) * (TURBO.len() - 1) as f32;
    let i = (x.floor() as usize).min(TURBO.len() - 2);
    let f = x - i as f32;
    let (a, b) = (TURBO[i], TURBO[i + 1]);
    std::array::from_fn(|c| (f32::from(a[c]) * (1.0 - f) + f32::from(b[c]) * f) / 255.0)
}

/// Where [`Image::from_depth`] puts its legend, for an image of `width` × `height` and a range (near, far).
#[derive(Debug)]
struct DepthLegend {
    /// The whole picture.
    width: usize,
    height: usize,
    /// Font pixel size; margins and the bar scale with it.
    scale: usize,
    /// Margin around the legend.
    pad: usize,
    bar_top: usize,
    bar_height: usize,
    text_top: usize,
    /// The range's ends as written: "0.42 m", "3.87 m".
    labels: [String; 2],
}

impl DepthLegend {
    fn new(width: usize, height: usize, near: f32, far: f32) -> DepthLegend {
        let scale = (width.saturating_add(120) / 240).max(1);
        // Two decimals, more (up to 6) when two would write both ends the same or a positive minimum as 0.
        let label = |v: f32, decimals: usize| format!("{v:.decimals$} m");
        let readable = |d: usize| {
            (near == far || label(near, d) != label(far, d))
                && (near == 0.0 || format!("{near:.d$}") != format!("{:.d$}", 0.0))
        };
        let decimals = (2..6).find(|&d| readable(d)).unwrap_or(6);
        let labels = [label(near, decimals), label(far, decimals)];
        let pad = 2 * scale;
        let gap = 3 * font::ADVANCE * scale;
        let legend = pad + font::text_width(&labels[0], scale) + gap + font::text_width(&labels[1], scale) + pad;
        let bar_height = 4 * scale;
        let bar_top = height + pad;
        let text_top = bar_top + bar_height + 2 * scale;
        DepthLegend {
            width: width.max(legend),
            height: text_top + font::GLYPH_HEIGHT * scale + pad,
            scale,
            pad,
            bar_top,
            bar_height,
            text_top,
            labels,
        }
    }
}

/// An RGB image: `width` × `height` pixels, row-major from the top row, three f32 channels per pixel; the
/// model's inputs and outputs are in [0, 1].
///
/// ```
/// use raypatch::Image;
/// let image = Image::new(2, 1, vec![0.0, 0.5, 1.0, 1.0, 1.0, 1.0])?;
/// assert_eq!(image.pixel(0, 0), [0.0, 0.5, 1.0]);
/// assert_eq!(image.to_rgb8(), vec![0, 128, 255, 255, 255, 255]);
/// # Ok::<(), raypatch::Error>(())
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    width: usize,
    height: usize,
    data: Vec<f32>,
}

impl Image {
    /// An image from `width * height * 3` values; NaN and infinity are rejected.
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Result<Image> {
        let expected = width.checked_mul(height).and_then(|p| p.checked_mul(3));
        if Some(data.len()) != expected {
            return Err(Error::Image {
                path: "image".into(),
                reason: format!("{} values for {width}x{height} RGB pixels (expected 3 per pixel)", data.len()),
            });
        }
        if let Some(i) = data.iter().position(|v| !v.is_finite()) {
            return Err(Error::Image {
                path: "image".into(),
                reason: format!("value {i} is {} (NaN or infinity)", data[i]),
            });
        }
        Ok(Image { width, height, data })
    }

    /// Reads a PNG (8 or 16 bits, grey or RGB, with or without alpha). Alpha is composited onto white, the
    /// background of NeRF's Blender scenes. The size the PNG declares is checked against
    /// [`MAX_IMAGE_SIDE`] and [`MAX_IMAGE_PIXELS`] before anything is decoded.
    pub fn load_png(path: impl AsRef<Path>) -> Result<Image> {
        let path = path.as_ref();
        let bytes = raypatch_model::files::read_regular(path, MAX_PNG_BYTES)
            .map_err(|e| Error::io(path, "cannot read", e.into()))?;
        Image::decode_png(&path.display().to_string(), &bytes)
    }

    /// Decodes the bytes of a PNG file as [`load_png`](Self::load_png) does; `name` stands for the file in
    /// messages.
    pub fn decode_png(name: &str, bytes: &[u8]) -> Result<Image> {
        let bad = |reason: String| Error::Image { path: name.to_string(), reason };
        let reader = || image::ImageReader::with_format(std::io::Cursor::new(bytes), image::ImageFormat::Png);
        let (width, height) = reader().into_dimensions().map_err(|e| bad(format!("not a readable PNG: {e}")))?;
        check_image_size(width as usize, height as usize).map_err(bad)?;
        let mut limits = image::Limits::default();
        // The decoder's buffers for an image of the checked size, with room for 16-bit RGBA.
        limits.max_alloc = Some(width as u64 * height as u64 * 8 + (1 << 20));
        let mut reader = reader();
        reader.limits(limits);
        let decoded = reader.decode().map_err(|e| bad(format!("not a readable PNG: {e}")))?;
        let rgba = decoded.into_rgba32f();
        let (width, height) = (rgba.width() as usize, rgba.height() as usize);
        let data = rgba.pixels().flat_map(|p| {
            let [r, g, b, a] = p.0;
            [r * a + (1.0 - a), g * a + (1.0 - a), b * a + (1.0 - a)]
        });
        Ok(Image { width, height, data: data.collect() })
    }

    /// The image as an 8-bit RGB PNG.
    pub fn encode_png(&self) -> Result<Vec<u8>> {
        let rgb = image::RgbImage::from_raw(self.width as u32, self.height as u32, self.to_rgb8())
            .expect("an Image always holds width * height * 3 values");
        let mut png = Vec::new();
        rgb.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .map_err(|e| Error::Image { path: "image".into(), reason: format!("cannot encode PNG: {e}") })?;
        Ok(png)
    }

    /// Writes an 8-bit RGB PNG through a temporary file and a rename (see [`write_atomic`]).
    #[cfg(not(target_family = "wasm"))]
    pub fn save_png(&self, path: impl AsRef<Path>) -> Result<()> {
        write_atomic(path.as_ref(), &self.encode_png()?)
    }

    /// A segmentation as colours: each pixel takes the colour of its most-weighted slot from a fixed palette
    /// of 12 distinct colours (slot 12 repeats slot 0's). `weights`: `[height, width, slots]` row-major.
    pub fn from_segmentation(width: usize, height: usize, weights: &[f32], slots: usize) -> Result<Image> {
        const PALETTE: [[u8; 3]; 12] = [
            [230, 25, 75],
            [60, 180, 75],
            [255, 225, 25],
            [0, 130, 200],
            [245, 130, 48],
            [145, 30, 180],
            [70, 240, 240],
            [240, 50, 230],
            [210, 245, 60],
            [250, 190, 212],
            [0, 128, 128],
            [170, 110, 40],
        ];
        if slots == 0 || weights.len() != width * height * slots {
            return Err(Error::Image {
                path: "segmentation".into(),
                reason: format!("{} slot weights for a {width}x{height} image of {slots} slots", weights.len()),
            });
        }
        let data = slot_ids(weights, slots)
            .flat_map(|slot| PALETTE[slot % PALETTE.len()].map(|c| f32::from(c) / 255.0))
            .collect();
        Image::new(width, height, data)
    }

    /// Depth as a picture with a legend: each pixel coloured by its depth with the turbo colour map, near
    /// warm (dark red at the range's minimum) and far cool (dark blue at its maximum), values outside the range
    /// taking the end colours, and pixels without depth (0, negative, NaN or infinity: ground truth's missing
    /// values) black. Below the image, on white, a colour bar from the minimum (left) to the maximum (right)
    /// with both written in metres under its ends ("0.42 m", "3.87 m"; more decimals when two would make them
    /// equal, or a positive minimum as 0). The picture is at least as wide as the legend needs (the image is centred in it), and the
    /// legend's text grows with the image (one font pixel per 240 image columns).
    ///
    /// `depth`: `[height, width]` row-major in metres. `range`: (min, max) with 0 ≤ min < max, or `None` for
    /// the depth's own minimum and maximum over its valid pixels (an error when it has none).
    ///
    /// ```
    /// use raypatch::Image;
    /// let depth = [0.5, 1.0, 2.0, f32::NAN];
    /// let picture = Image::from_depth(2, 2, &depth, None)?;
    /// assert!(picture.width() >= 2 && picture.height() > 2);
    /// assert_eq!(picture.pixel(picture.width() / 2 - 1, 0), Image::depth_colour(0.5, (0.5, 2.0)));
    /// assert_eq!(picture.pixel(picture.width() / 2, 1), [0.0; 3]); // no depth: black
    /// # Ok::<(), raypatch::Error>(())
    /// ```
    pub fn from_depth(width: usize, height: usize, depth: &[f32], range: Option<(f32, f32)>) -> Result<Image> {
        let bad = |reason: String| Error::Image { path: "depth".into(), reason };
        if width == 0 || height == 0 || Some(depth.len()) != width.checked_mul(height) {
            return Err(bad(format!("{} depth values for a {width}x{height} image", depth.len())));
        }
        let (near, far) = match range {
            Some((lo, hi)) if lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo < hi => (lo, hi),
            Some((lo, hi)) => return Err(bad(format!("depth range {lo},{hi}: expected 0 <= MIN < MAX, in metres"))),
            None => depth
                .iter()
                .copied()
                .filter(|&d| has_depth(d))
                .fold(None, |r, d| match r {
                    None => Some((d, d)),
                    Some((lo, hi)) => Some((d.min(lo), d.max(hi))),
                })
                .ok_or_else(|| bad("no pixel has a depth (finite and positive) to set the colour range from".into()))?,
        };
        let layout = DepthLegend::new(width, height, near, far);
        let (cw, ch) = (layout.width, layout.height);
        check_image_size(cw, ch).map_err(bad)?;
        let mut data = vec![1.0; cw * ch * 3];
        let x0 = (cw - width) / 2;
        for y in 0..height {
            for x in 0..width {
                let colour = Image::depth_colour(depth[y * width + x], (near, far));
                data[(y * cw + x0 + x) * 3..][..3].copy_from_slice(&colour);
            }
        }
        let (bar_start, bar_len) = (layout.pad, cw - 2 * layout.pad);
        for x in 0..bar_len {
            let f = if bar_len > 1 { x as f32 / (bar_len - 1) as f32 } else { 0.0 };
            let colour = Image::depth_colour(near + f * (far - near), (near, far));
            for y in layout.bar_top..layout.bar_top + layout.bar_height {
                data[(y * cw + bar_start + x) * 3..][..3].copy_from_slice(&colour);
            }
        }
        let [low, high] = &layout.labels;
        let scale = layout.scale;
        font::draw_text(&mut data, cw, layout.pad, layout.text_top, low, scale, [0.0; 3]);
        let right = cw - layout.pad - font::text_width(high, scale);
        font::draw_text(&mut data, cw, right, layout.text_top, high, scale, [0.0; 3]);
        Image::new(cw, ch, data)
    }

    /// The colour [`from_depth`](Self::from_depth) gives a depth with a colour range (min, max): turbo from dark
    /// red at min to dark blue at max (clamped outside), black without depth (0, negative, NaN, infinity). A
    /// range whose ends are equal gives every depth min's colour.
    ///
    /// ```
    /// use raypatch::Image;
    /// let near = Image::depth_colour(1.0, (1.0, 3.0));
    /// let far = Image::depth_colour(3.0, (1.0, 3.0));
    /// assert!(near[0] > near[2] && far[2] > far[0]); // warm near, cool far
    /// assert_eq!(Image::depth_colour(0.5, (1.0, 3.0)), near);
    /// assert_eq!(Image::depth_colour(0.0, (1.0, 3.0)), [0.0; 3]);
    /// ```
    pub fn depth_colour(depth: f32, (min, max): (f32, f32)) -> [f32; 3] {
        if !has_depth(depth) {
            return [0.0; 3];
        }
        let t = if max > min { ((depth - min) / (max - min)).clamp(0.0, 1.0) } else { 0.0 };
        turbo(1.0 - t)
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// All values, `[height, width, 3]` row-major.
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// The pixel at column `x`, row `y`.
    pub fn pixel(&self, x: usize, y: usize) -> [f32; 3] {
        let i = (y * self.width + x) * 3;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    /// 8-bit values, clamped to [0, 1] and rounded.
    pub fn to_rgb8(&self) -> Vec<u8> {
        self.data.iter().map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8).collect()
    }

    /// The pixels inside `region`, which must lie inside the image.
    ///
    /// ```
    /// use raypatch::{Image, Region};
    /// let image = Image::new(3, 2, (0..18).map(|v| v as f32 / 17.0).collect())?;
    /// let right = image.crop(Region { x: 2, y: 0, width: 1, height: 2 })?;
    /// assert_eq!(right.pixel(0, 1), image.pixel(2, 1));
    /// # Ok::<(), raypatch::Error>(())
    /// ```
    pub fn crop(&self, region: Region) -> Result<Image> {
        let Region { x, y, width, height } = region;
        if !region.lies_within(self.width, self.height) {
            return Err(Error::Image {
                path: "image".into(),
                reason: format!(
                    "region {x},{y},{width},{height} is not inside the {}x{} image",
                    self.width, self.height
                ),
            });
        }
        let mut data = Vec::with_capacity(width * height * 3);
        for row in y..y + height {
            let start = (row * self.width + x) * 3;
            data.extend_from_slice(&self.data[start..start + width * 3]);
        }
        Ok(Image { width, height, data })
    }
}

/// Each pixel's most-weighted slot, from slot weights `[pixels, slots]` (the first one on ties, as `argmax`).
pub fn slot_ids(weights: &[f32], slots: usize) -> impl Iterator<Item = usize> + '_ {
    weights.chunks_exact(slots).map(|w| {
        w.iter().enumerate().fold((0, f32::NEG_INFINITY), |best, (i, &v)| if v > best.1 { (i, v) } else { best }).0
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The picture's pixel (x, y).
    fn at(image: &Image, x: usize, y: usize) -> [f32; 3] {
        image.pixel(x, y)
    }

    /// Reads the text written in the legend row: `from_left` reads glyph cells from x = `start` rightwards,
    /// else from the cell ending at `start` leftwards, until three blank cells.
    fn read_text(image: &Image, layout: &DepthLegend, start: usize, from_left: bool) -> String {
        let s = layout.scale;
        let step = font::ADVANCE * s;
        let cell = |left: usize| -> Option<char> {
            let dark = |gx: usize, gy: usize| {
                let (x, y) = (left + gx * s + s / 2, layout.text_top + gy * s + s / 2);
                at(image, x, y) == [0.0; 3]
            };
            "0123456789.m ".chars().find(|&c| {
                let g = font::glyph(c).unwrap();
                (0..font::GLYPH_HEIGHT)
                    .all(|gy| (0..font::GLYPH_WIDTH).all(|gx| dark(gx, gy) == font::is_set(&g, gx, gy)))
            })
        };
        let mut chars = Vec::new();
        for n in 0.. {
            let left = if from_left {
                start + n * step
            } else {
                match (start + s).checked_sub((n + 1) * step) {
                    Some(left) => left,
                    None => break,
                }
            };
            if left + font::GLYPH_WIDTH * s > image.width() {
                break;
            }
            let c = cell(left).expect("every cell holds a glyph of the font or is blank");
            chars.push(c);
            if chars.len() >= 3 && chars[chars.len() - 3..].iter().all(|&c| c == ' ') {
                break;
            }
        }
        if !from_left {
            chars.reverse();
        }
        chars.into_iter().collect::<String>().trim().to_string()
    }

    #[test]
    fn turbo_runs_from_dark_blue_to_dark_red_through_the_stops() {
        assert_eq!(turbo(0.0), TURBO[0].map(|c| f32::from(c) / 255.0));
        assert_eq!(turbo(1.0), TURBO[16].map(|c| f32::from(c) / 255.0));
        assert_eq!(turbo(0.5), TURBO[8].map(|c| f32::from(c) / 255.0));
        // Halfway between two stops: their mean.
        let mid = turbo(1.5 / 16.0);
        for c in 0..3 {
            let mean = (f32::from(TURBO[1][c]) + f32::from(TURBO[2][c])) / 2.0 / 255.0;
            assert!((mid[c] - mean).abs() < 1e-6);
        }
        assert_eq!(turbo(-1.0), turbo(0.0));
        assert_eq!(turbo(2.0), turbo(1.0));
        // Near is warm, far cool; missing depth is black.
        let range = (1.0, 5.0);
        let (near, far) = (Image::depth_colour(1.0, range), Image::depth_colour(5.0, range));
        assert!(near[0] > 0.4 && near[2] < 0.05 && far[2] > 0.2 && far[0] < 0.2, "{near:?} {far:?}");
        for missing in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            assert_eq!(Image::depth_colour(missing, range), [0.0; 3]);
        }
        assert_eq!(Image::depth_colour(9.0, range), far);
        assert_eq!(Image::depth_colour(3.0, (3.0, 3.0)), near);
    }

    #[test]
    fn depth_picture_has_the_image_a_colour_bar_and_its_range_in_metres() {
        let (w, h) = (40, 8);
        let depth: Vec<f32> = (0..w * h).map(|i| 0.42 + 3.45 * (i % w) as f32 / (w - 1) as f32).collect();
        let mut with_holes = depth.clone();
        with_holes[0] = 0.0;
        with_holes[w + 1] = f32::NAN;
        let picture = Image::from_depth(w, h, &with_holes, None).unwrap();
        // The holes at (0, 0) and (1, 1) leave 0.42 at (0, 1).
        let (near, far) = (depth[0], depth[w - 1]);
        assert!((near - 0.42).abs() < 1e-6 && (far - 3.87).abs() < 1e-6);
        let layout = DepthLegend::new(w, h, near, far);
        assert_eq!((picture.width(), picture.height()), (layout.width, layout.height));
        assert!(picture.width() > w, "the legend needs more than 40 pixels");
        let x0 = (picture.width() - w) / 2;
        // The image, centred; its range is that of its valid pixels (the holes are black).
        assert_eq!(at(&picture, x0, 0), [0.0; 3]);
        assert_eq!(at(&picture, x0 + 1, 1), [0.0; 3]);
        for (x, y) in [(1, 0), (w - 1, 0), (7, 5)] {
            assert_eq!(at(&picture, x0 + x, y), Image::depth_colour(depth[y * w + x], (near, far)));
        }
        assert_eq!(at(&picture, x0 + 2, 3), Image::depth_colour(depth[2], (near, far)));
        // White around the image.
        assert_eq!(at(&picture, 0, 0), [1.0; 3]);
        assert_eq!(at(&picture, picture.width() - 1, h - 1), [1.0; 3]);
        // The bar: near (left) to far (right), every pixel the colour of its depth.
        let (left, right) = (layout.pad, picture.width() - layout.pad - 1);
        for y in layout.bar_top..layout.bar_top + layout.bar_height {
            assert_eq!(at(&picture, left, y), Image::depth_colour(near, (near, far)));
            assert_eq!(at(&picture, right, y), Image::depth_colour(far, (near, far)));
            for x in left..=right {
                let f = (x - left) as f32 / (right - left) as f32;
                let d = near + f * (far - near);
                assert_eq!(at(&picture, x, y), Image::depth_colour(d, (near, far)), "bar ({x}, {y})");
            }
        }
        assert_eq!(at(&picture, left - 1, layout.bar_top), [1.0; 3]);
        assert_eq!(at(&picture, left, layout.bar_top - 1), [1.0; 3]);
        // The text: the range's ends, read back from the pixels.
        assert_eq!(read_text(&picture, &layout, left, true), "0.42 m");
        assert_eq!(read_text(&picture, &layout, right + 1, false), "3.87 m");
        // Only black text and white between the bar and the bottom.
        for y in layout.bar_top + layout.bar_height..picture.height() {
            for x in 0..picture.width() {
                let p = at(&picture, x, y);
                assert!(p == [0.0; 3] || p == [1.0; 3], "({x}, {y}) is {p:?}");
            }
        }
    }

    #[test]
    fn a_fixed_range_clamps_and_labels_grow_with_the_image() {
        let (w, h) = (640, 480);
        let depth: Vec<f32> = (0..w * h).map(|i| 0.5 + 9.0 * (i / w) as f32 / h as f32).collect();
        let picture = Image::from_depth(w, h, &depth, Some((1.0, 4.0))).unwrap();
        let layout = DepthLegend::new(w, h, 1.0, 4.0);
        assert_eq!((picture.width(), layout.scale), (w, 3));
        assert_eq!(picture.height(), h + 2 * 6 + 12 + 6 + 21);
        assert_eq!(at(&picture, 0, 0), Image::depth_colour(1.0, (1.0, 4.0)), "0.5 m takes the near end's colour");
        assert_eq!(at(&picture, 0, h - 1), Image::depth_colour(4.0, (1.0, 4.0)), "9.5 m takes the far end's colour");
        assert_eq!(read_text(&picture, &layout, layout.pad, true), "1.00 m");
        assert_eq!(read_text(&picture, &layout, w - layout.pad, false), "4.00 m");
    }

    #[test]
    fn labels_keep_enough_decimals_and_bad_ranges_are_errors() {
        assert_eq!(DepthLegend::new(8, 8, 1.0, 1.004).labels, ["1.000 m".to_string(), "1.004 m".to_string()]);
        assert_eq!(DepthLegend::new(8, 8, 0.003, 2.0).labels, ["0.003 m".to_string(), "2.000 m".to_string()]);
        assert_eq!(DepthLegend::new(8, 8, 2.5, 2.5).labels, ["2.50 m".to_string(), "2.50 m".to_string()]);
        // One valid value: every valid pixel takes the near colour.
        let one = Image::from_depth(2, 1, &[2.5, 0.0], None).unwrap();
        let x0 = (one.width() - 2) / 2;
        assert_eq!((at(&one, x0, 0), at(&one, x0 + 1, 0)), (Image::depth_colour(2.5, (2.5, 2.5)), [0.0; 3]));
        for range in [(2.0, 1.0), (1.0, 1.0), (-1.0, 1.0), (0.0, f32::INFINITY), (f32::NAN, 1.0)] {
            let e = Image::from_depth(1, 1, &[1.0], Some(range)).unwrap_err().to_string();
            assert!(e.contains("0 <= MIN < MAX"), "{range:?}: {e}");
        }
        let e = Image::from_depth(2, 1, &[0.0, f32::NAN], None).unwrap_err().to_string();
        assert!(e.contains("no pixel has a depth"), "{e}");
        assert!(Image::from_depth(2, 2, &[1.0; 3], None).unwrap_err().to_string().contains("3 depth values"));
    }
}
