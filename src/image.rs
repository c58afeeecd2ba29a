//! RGB images in f32.

use std::path::Path;

use crate::error::{Error, Result};
use crate::Region;

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
        if data.len() != width * height * 3 {
            return Err(Error::Image {
                path: "image".into(),
                reason: format!(
                    "{} values for {width}x{height} RGB pixels (expected {})",
                    data.len(),
                    width * height * 3
                ),
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
    /// background of NeRF's Blender scenes.
    pub fn load_png(path: impl AsRef<Path>) -> Result<Image> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, "cannot read", e))?;
        let decoded = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png).map_err(|e| {
            Error::Image { path: path.display().to_string(), reason: format!("not a readable PNG: {e}") }
        })?;
        let rgba = decoded.into_rgba32f();
        let (width, height) = (rgba.width() as usize, rgba.height() as usize);
        let data = rgba.pixels().flat_map(|p| {
            let [r, g, b, a] = p.0;
            [r * a + (1.0 - a), g * a + (1.0 - a), b * a + (1.0 - a)]
        });
        Ok(Image { width, height, data: data.collect() })
    }

    /// Writes an 8-bit RGB PNG through a temporary file and a rename, so a failed write leaves no file.
    pub fn save_png(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let rgb = image::RgbImage::from_raw(self.width as u32, self.height as u32, self.to_rgb8())
            .expect("an Image always holds width * height * 3 values");
        let mut png = Vec::new();
        rgb.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).map_err(|e| Error::Image {
            path: path.display().to_string(),
            reason: format!("cannot encode PNG: {e}"),
        })?;
        write_atomic(path, &png)
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
        if x + width > self.width || y + height > self.height {
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

/// Writes `bytes` to `path` through a temporary file in the same folder and a rename, so that no partial
/// file is left behind; the temporary file is removed when the write fails.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tmp = path.with_file_name(format!(".{name}.tmp"));
    let written = std::fs::write(&tmp, bytes).and_then(|()| std::fs::rename(&tmp, path));
    written.map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        Error::io(path, "cannot write", e)
    })
}
