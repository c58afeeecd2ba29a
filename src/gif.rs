//! Animated GIFs written a frame at a time (a video's frames streamed to its file).

use crate::error::{Error, Result};
use crate::image::Image;

/// An animated GIF that loops, written a frame at a time (nothing but the current frame is held), `fps` frames
/// per second (GIF delays are whole hundredths of a second: 24 fps plays at 25). Colours are quantised to each
/// frame's own 256-colour palette; the animation is the first frame's size.
///
/// ```
/// use raypatch::{GifWriter, Image};
/// let mut gif = Vec::new();
/// let mut writer = GifWriter::new(&mut gif, 12.0)?;
/// for shade in [0.2, 0.8] {
///     writer.push(&Image::new(4, 2, vec![shade; 24])?)?;
/// }
/// writer.finish()?;
/// assert!(gif.starts_with(b"GIF89a") && gif.ends_with(&[0x3B])); // the trailer ends the file
/// assert!(GifWriter::new(Vec::new(), 12.0)?.finish().is_err()); // no frame
/// # Ok::<(), raypatch::Error>(())
/// ```
pub struct GifWriter<W: std::io::Write> {
    out: Option<W>,
    encoder: Option<gif::Encoder<W>>,
    /// Hundredths of a second per frame.
    delay: u16,
}

impl<W: std::io::Write> GifWriter<W> {
    pub fn new(out: W, fps: f64) -> Result<GifWriter<W>> {
        if !(fps.is_finite() && fps > 0.0) {
            return Err(gif_error(format!("GIF frame rate {fps}: expected a positive number of frames per second")));
        }
        let delay = (100.0 / fps.round().max(1.0)).round().clamp(1.0, u16::MAX as f64) as u16;
        Ok(GifWriter { out: Some(out), encoder: None, delay })
    }

    /// Appends `frame` to the animation.
    pub fn push(&mut self, frame: &Image) -> Result<()> {
        let (width, height) = (frame.width() as u16, frame.height() as u16);
        let encoder = match (&mut self.encoder, self.out.take()) {
            (Some(encoder), _) => encoder,
            (None, Some(out)) => {
                let mut encoder = gif::Encoder::new(out, width, height, &[]).map_err(encoding)?;
                encoder.set_repeat(gif::Repeat::Infinite).map_err(encoding)?;
                self.encoder.insert(encoder)
            }
            (None, None) => unreachable!("a GifWriter holds its output or its encoder"),
        };
        let mut rgba: Vec<u8> = frame.to_rgb8().chunks_exact(3).flat_map(|p| [p[0], p[1], p[2], 255]).collect();
        let mut gif_frame = gif::Frame::from_rgba_speed(width, height, &mut rgba, 10);
        gif_frame.delay = self.delay;
        encoder.write_frame(&gif_frame).map_err(encoding)
    }

    /// Writes the trailer and gives the output back: an error here (a full disk) is an error of the GIF.
    pub fn finish(self) -> Result<W> {
        match (self.encoder, self.out) {
            (Some(encoder), _) => encoder.into_inner().map_err(encoding),
            (None, _) => Err(gif_error("an animated GIF needs at least one frame".into())),
        }
    }
}

fn encoding(e: gif::EncodingError) -> Error {
    gif_error(format!("cannot encode GIF: {e}"))
}

fn gif_error(reason: String) -> Error {
    Error::Image { path: "image".into(), reason }
}
