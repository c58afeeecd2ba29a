//! A tiny bitmap font for the legends and labels drawn into images (the image crate draws no text): 5×7
//! glyphs for the digits, the lowercase letters, `.` and ` `: lengths such as "0.42 m" and panel labels.

/// Glyph width in font pixels.
pub const GLYPH_WIDTH: usize = 5;
/// Glyph height in font pixels.
pub const GLYPH_HEIGHT: usize = 7;
/// Horizontal step from one character to the next, in font pixels: the glyph and one column of space.
pub const ADVANCE: usize = GLYPH_WIDTH + 1;

/// The glyph of `c`, one byte per row from the top, the row's 5 pixels in the low 5 bits (bit 4 = leftmost);
/// `None` for a character the font lacks.
pub fn glyph(c: char) -> Option<[u8; GLYPH_HEIGHT]> {
    Some(match c {
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        '.' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C],
        'm' => [0x00, 0x00, 0x1A, 0x15, 0x15, 0x11, 0x11],
        'a' => [0x00, 0x00, 0x0E, 0x01, 0x0F, 0x11, 0x0F],
        'b' => [0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x1E],
        'c' => [0x00, 0x00, 0x0E, 0x10, 0x10, 0x11, 0x0E],
        'd' => [0x01, 0x01, 0x0D, 0x13, 0x11, 0x11, 0x0F],
        'e' => [0x00, 0x00, 0x0E, 0x11, 0x1F, 0x10, 0x0E],
        'f' => [0x06, 0x09, 0x08, 0x1C, 0x08, 0x08, 0x08],
        'g' => [0x00, 0x0F, 0x11, 0x11, 0x0F, 0x01, 0x0E],
        'h' => [0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x11],
        'i' => [0x04, 0x00, 0x0C, 0x04, 0x04, 0x04, 0x0E],
        'j' => [0x02, 0x00, 0x06, 0x02, 0x02, 0x12, 0x0C],
        'k' => [0x10, 0x10, 0x12, 0x14, 0x18, 0x14, 0x12],
        'l' => [0x0C, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'n' => [0x00, 0x00, 0x16, 0x19, 0x11, 0x11, 0x11],
        'o' => [0x00, 0x00, 0x0E, 0x11, 0x11, 0x11, 0x0E],
        'p' => [0x00, 0x00, 0x1E, 0x11, 0x1E, 0x10, 0x10],
        'q' => [0x00, 0x00, 0x0D, 0x13, 0x0F, 0x01, 0x01],
        'r' => [0x00, 0x00, 0x16, 0x19, 0x10, 0x10, 0x10],
        's' => [0x00, 0x00, 0x0E, 0x10, 0x0E, 0x01, 0x1E],
        't' => [0x08, 0x08, 0x1C, 0x08, 0x08, 0x09, 0x06],
        'u' => [0x00, 0x00, 0x11, 0x11, 0x11, 0x13, 0x0D],
        'v' => [0x00, 0x00, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'w' => [0x00, 0x00, 0x11, 0x11, 0x15, 0x15, 0x0A],
        'x' => [0x00, 0x00, 0x11, 0x0A, 0x04, 0x0A, 0x11],
        'y' => [0x00, 0x00, 0x11, 0x11, 0x0F, 0x01, 0x0E],
        'z' => [0x00, 0x00, 0x1F, 0x02, 0x04, 0x08, 0x1F],
        ' ' => [0x00; GLYPH_HEIGHT],
        _ => return None,
    })
}

/// Whether glyph `g` has its pixel at column `x`, row `y` set.
pub fn is_set(g: &[u8; GLYPH_HEIGHT], x: usize, y: usize) -> bool {
    g[y] >> (GLYPH_WIDTH - 1 - x) & 1 == 1
}

/// Width in pixels of `text` drawn at `scale` (from the first glyph's left edge to the last one's right edge).
pub fn text_width(text: &str, scale: usize) -> usize {
    let n = text.chars().count();
    (n * ADVANCE).saturating_sub(1) * scale
}

/// Draws `text` with its top-left corner at (`x`, `y`) into an RGB canvas (`[rows, width, 3]` row-major), each
/// font pixel a `scale` × `scale` square of `colour`. Pixels outside the canvas are left out; characters the
/// font lacks draw nothing (see [`glyph`]).
pub fn draw_text(canvas: &mut [f32], width: usize, x: usize, y: usize, text: &str, scale: usize, colour: [f32; 3]) {
    let rows = canvas.len() / 3 / width.max(1);
    for (n, c) in text.chars().enumerate() {
        let Some(g) = glyph(c) else { continue };
        let left = x + n * ADVANCE * scale;
        for gy in 0..GLYPH_HEIGHT {
            for gx in (0..GLYPH_WIDTH).filter(|&gx| is_set(&g, gx, gy)) {
                for py in y + gy * scale..y + (gy + 1) * scale {
                    for px in left + gx * scale..left + (gx + 1) * scale {
                        if px < width && py < rows {
                            canvas[(py * width + px) * 3..][..3].copy_from_slice(&colour);
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_glyph_is_distinct_and_fits_its_box() {
        let chars = "0123456789. abcdefghijklmnopqrstuvwxyz";
        for (i, a) in chars.chars().enumerate() {
            let g = glyph(a).unwrap();
            assert!(g.iter().all(|row| row >> GLYPH_WIDTH == 0), "{a:?} is wider than {GLYPH_WIDTH}");
            for b in chars.chars().skip(i + 1) {
                assert_ne!(g, glyph(b).unwrap(), "{a:?} and {b:?} look the same");
            }
        }
        assert!(glyph('X').is_none() && glyph('-').is_none());
    }

    #[test]
    fn text_is_drawn_where_and_as_large_as_asked() {
        let (width, rows) = (20, 10);
        let mut canvas = vec![1.0; width * rows * 3];
        draw_text(&mut canvas, width, 1, 2, "1", 1, [0.0; 3]);
        let one = glyph('1').unwrap();
        for y in 0..rows {
            for x in 0..width {
                let inside = (1..1 + GLYPH_WIDTH).contains(&x) && (2..2 + GLYPH_HEIGHT).contains(&y);
                let set = inside && is_set(&one, x - 1, y - 2);
                assert_eq!(canvas[(y * width + x) * 3] == 0.0, set, "pixel ({x}, {y})");
            }
        }
        // Scale 2: each font pixel is 2x2; text running off the canvas is clipped.
        let mut canvas = vec![1.0; width * 16 * 3];
        draw_text(&mut canvas, width, 0, 0, "88", 2, [0.0; 3]);
        let dark = canvas.chunks_exact(3).filter(|p| p[0] == 0.0).count();
        let eight = glyph('8').unwrap().iter().map(|r| r.count_ones() as usize).sum::<usize>();
        assert!(dark > 4 * eight && dark < 8 * eight, "{dark} dark pixels");
        assert_eq!(text_width("0.42 m", 1), 35);
        assert_eq!(text_width("0.42 m", 3), 105);
    }
}
