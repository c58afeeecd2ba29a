//! RGB images in f32.

use std::path::Path;

use crate::error::{Error, Result};
use crate::output::write_atomic;
use crate::Region;

/// Longest image side accepted, in pixels: images are checked before they are decoded or rendered.
pub const MAX_IMAGE_SIDE: usize = 16384;
/// Most pixels in one image (4096 x 4096): 200 MB as f32 RGB, beyond what one GPU buffer of the encoder or
/// the decoder holds on most adapters.
pub const MAX_IMAGE_PIXELS: usize = 1 << 24;
/// Largest PNG file read.
const MAX_PNG_BYTES: u64 = 1 << 30;

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
    pub fn save_png(&self, path: impl AsRef<Path>) -> Result<()> {
        write_atomic(path.as_ref(), &self.encode_png()?)
    }

    /// Width in pixels.
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
        let data = crate::metrics::slot_ids(weights, slots)
            .flat_map(|slot| PALETTE[slot % PALETTE.len()].map(|c| f32::from(c) / 255.0))
            .collect();
        Image::new(width, height, data)
    }

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
