//! Pictures laid out side by side with a label above each (a video frame's colour, depth, masks and input).

use crate::error::Result;
use crate::font;
use crate::image::Image;

/// `panels` left to right, each under its label (black on white, in the bitmap font, one font pixel per 240
/// columns of the widest panel), top-aligned on white, a gap between them; the width and height are rounded
/// up to even numbers (white), as H.264 video needs.
///
/// ```
/// use raypatch::{side_by_side, Image};
/// let red = Image::new(8, 6, [1.0, 0.0, 0.0].repeat(48))?;
/// let blue = Image::new(10, 4, [0.0, 0.0, 1.0].repeat(40))?;
/// let both = side_by_side(&[("rgb", &red), ("depth", &blue)])?;
/// assert!(both.width() > 18 && both.height() > 6 && both.width() % 2 == 0 && both.height() % 2 == 0);
/// let has = |colour: [f32; 3]| both.data().chunks(3).filter(|p| *p == colour).count();
/// assert_eq!((has([1.0, 0.0, 0.0]), has([0.0, 0.0, 1.0])), (48, 40)); // both panels, whole
/// assert!(has([0.0; 3]) > 0); // the labels
/// # Ok::<(), raypatch::Error>(())
/// ```
pub fn side_by_side(panels: &[(&str, &Image)]) -> Result<Image> {
    let widest = panels.iter().map(|(_, p)| p.width()).max().unwrap_or(1);
    let scale = (widest.saturating_add(120) / 240).max(1);
    let (pad, label_height) = (4 * scale, font::GLYPH_HEIGHT * scale + 4 * scale);
    let width = panels.iter().map(|(label, p)| p.width().max(font::text_width(label, scale))).sum::<usize>()
        + pad * panels.len().saturating_sub(1);
    let height = label_height + panels.iter().map(|(_, p)| p.height()).max().unwrap_or(1);
    let (width, height) = (width.next_multiple_of(2), height.next_multiple_of(2));
    crate::image::check_image_size(width, height)
        .map_err(|reason| crate::Error::Image { path: "panels".into(), reason })?;
    let mut data = vec![1.0; width * height * 3];
    let mut x0 = 0;
    for (label, panel) in panels {
        let column = panel.width().max(font::text_width(label, scale));
        font::draw_text(
            &mut data,
            width,
            x0 + (column - font::text_width(label, scale)) / 2,
            2 * scale,
            label,
            scale,
            [0.0; 3],
        );
        let left = x0 + (column - panel.width()) / 2;
        for y in 0..panel.height() {
            let row = &panel.data()[y * panel.width() * 3..(y + 1) * panel.width() * 3];
            data[((label_height + y) * width + left) * 3..][..row.len()].copy_from_slice(row);
        }
        x0 += column + pad;
    }
    Image::new(width, height, data)
}

/// `image` scaled to `height` rows (nearest pixel), keeping its aspect ratio.
pub fn scaled_to_height(image: &Image, height: usize) -> Result<Image> {
    let width = ((image.width() * height) as f64 / image.height() as f64).round().max(1.0) as usize;
    let data = (0..height)
        .flat_map(|y| (0..width).map(move |x| (x * image.width() / width, y * image.height() / height)))
        .flat_map(|(x, y)| image.pixel(x, y))
        .collect();
    Image::new(width, height, data)
}
