//! Contact sheets: a labelled grid of RGBA views composited over white, the picture the demo
//! and `wonder3d generate` write so a person can check views at a glance.
//!
//! Labels use a built-in 5 × 7 pixel font (lower-case letters, digits and a little
//! punctuation), scaled by an integer factor, so no font file or font crate is needed.

use w3d_core::{Error, Image, Result};

/// One row of a contact sheet: a label drawn at its left and images of one common size.
#[derive(Debug, Clone)]
pub struct SheetRow {
    /// Text drawn in the margin at the left of the row (e.g. `input colour`).
    pub label: String,
    /// The row's images, RGBA (alpha composited over white) or RGB.
    pub images: Vec<Image>,
}

/// Width of a glyph cell in font pixels (5 columns + 1 spacing).
const CELL_W: usize = 6;
/// Height of a glyph in font pixels.
const GLYPH_H: usize = 7;

/// The 5 × 7 glyph of `c` as seven rows of five bits (most significant bit = leftmost
/// column); upper-case letters draw as lower-case, unknown characters as a box.
fn glyph(c: char) -> [u8; GLYPH_H] {
    match c.to_ascii_lowercase() {
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
        'm' => [0x00, 0x00, 0x1A, 0x15, 0x15, 0x11, 0x11],
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
        ' ' => [0; GLYPH_H],
        '_' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x1F],
        '-' => [0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00],
        '.' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C],
        ',' => [0x00, 0x00, 0x00, 0x00, 0x0C, 0x04, 0x08],
        ':' => [0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00],
        '/' => [0x00, 0x01, 0x02, 0x04, 0x08, 0x10, 0x00],
        '(' => [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02],
        ')' => [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08],
        '=' => [0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00],
        '%' => [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03],
        _ => [0x1F, 0x11, 0x11, 0x11, 0x11, 0x11, 0x1F],
    }
}

/// Width in image pixels of `text` drawn at `scale`.
fn text_width(text: &str, scale: usize) -> usize {
    text.chars().count() * CELL_W * scale
}

/// Draws `text` in black into an RGB `[H][W][3]` buffer of width `w`, top-left at `(x0, y0)`,
/// each font pixel `scale` × `scale` image pixels; pixels outside the buffer are skipped.
fn draw_text(data: &mut [f32], w: usize, x0: usize, y0: usize, text: &str, scale: usize) {
    let h = data.len() / (3 * w);
    for (i, c) in text.chars().enumerate() {
        let rows = glyph(c);
        for (gy, bits) in rows.iter().enumerate() {
            for gx in 0..5 {
                if bits & (0x10 >> gx) == 0 {
                    continue;
                }
                for sy in 0..scale {
                    for sx in 0..scale {
                        let x = x0 + (i * CELL_W + gx) * scale + sx;
                        let y = y0 + gy * scale + sy;
                        if x < w && y < h {
                            data[3 * (y * w + x)..3 * (y * w + x) + 3].fill(0.0);
                        }
                    }
                }
            }
        }
    }
}

/// Composites `image` (RGB, or RGBA over white) into 3 channels.
fn over_white(image: &Image) -> Result<Vec<f32>> {
    match image.channels() {
        3 => Ok(image.data().to_vec()),
        4 => Ok(image.data().chunks_exact(4).flat_map(|p| [0, 1, 2].map(|c| p[c] * p[3] + (1.0 - p[3]))).collect()),
        c => Err(Error::invalid("contact sheet image", format!("3 or 4 channels, got {c}"))),
    }
}

/// A labelled grid on white: `column_labels` above the columns (e.g. view names), each
/// row's label in a margin at the left. Every image must have the size of the first; the
/// label scale grows with the image size (2 font pixels per image pixel up to 256², more
/// above) so labels stay readable.
pub fn contact_sheet(column_labels: &[&str], rows: &[SheetRow]) -> Result<Image> {
    let first = rows
        .iter()
        .flat_map(|r| r.images.first())
        .next()
        .ok_or_else(|| Error::invalid("contact sheet", "at least one image"))?;
    let (w, h) = (first.width() as usize, first.height() as usize);
    let scale = (w / 128).max(1);
    let pad = 4 * scale;
    let line = GLYPH_H * scale + 2 * pad;
    let margin = rows.iter().map(|r| text_width(&r.label, scale)).max().unwrap_or(0) + 2 * pad;
    let columns = rows.iter().map(|r| r.images.len()).max().unwrap_or(0).max(column_labels.len());
    let top = if column_labels.is_empty() { 0 } else { line };
    let (sw, sh) = (margin + columns * w, top + rows.len() * h);
    let mut data = vec![1.0f32; sw * sh * 3];
    for (c, label) in column_labels.iter().enumerate() {
        let x = margin + c * w + w.saturating_sub(text_width(label, scale)) / 2;
        draw_text(&mut data, sw, x, pad, label, scale);
    }
    for (r, row) in rows.iter().enumerate() {
        let y0 = top + r * h;
        draw_text(&mut data, sw, pad, y0 + h.saturating_sub(GLYPH_H * scale) / 2, &row.label, scale);
        for (c, image) in row.images.iter().enumerate() {
            if (image.width() as usize, image.height() as usize) != (w, h) {
                return Err(Error::invalid(
                    format!("contact sheet row {:?} image {c}", row.label),
                    format!("{w}×{h} like the first image, got {}×{}", image.width(), image.height()),
                ));
            }
            let flat = over_white(image)?;
            for y in 0..h {
                let dst = 3 * ((y0 + y) * sw + margin + c * w);
                data[dst..dst + 3 * w].copy_from_slice(&flat[3 * y * w..3 * (y + 1) * w]);
            }
        }
    }
    Image::new(sw as u32, sh as u32, 3, data)
}

/// Normals as an RGBA picture: RGB = (n + 1) / 2 (the file convention), alpha = `mask`.
pub fn normal_picture(normal: &Image, mask: &Image) -> Result<Image> {
    let rgb: Vec<f32> = normal.data().iter().map(|v| 0.5 * (v + 1.0)).collect();
    Image::new(normal.width(), normal.height(), 3, rgb)?.with_alpha(mask)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_are_drawn_and_images_placed() {
        let red = Image::new(16, 16, 4, [1.0, 0.0, 0.0, 1.0].repeat(256)).unwrap();
        let rows = [SheetRow { label: "ab".into(), images: vec![red.clone(), red] }];
        let sheet = contact_sheet(&["x"], &rows).unwrap();
        // margin: 2 glyphs × 6 + 2 × 4 padding = 20 px; top line 7 + 8 = 15 px.
        assert_eq!((sheet.width(), sheet.height()), (20 + 2 * 16, 15 + 16));
        assert_eq!(sheet.pixel(20, 15), &[1.0, 0.0, 0.0]);
        assert_eq!(sheet.pixel(51, 30), &[1.0, 0.0, 0.0]);
        let dark = sheet.data().chunks_exact(3).filter(|p| p == &[0.0, 0.0, 0.0]).count();
        assert!(dark > 10, "the labels left {dark} black pixels");
    }

    #[test]
    fn mismatched_sizes_are_an_error() {
        let a = Image::filled(2, 2, 3, 0.5).unwrap();
        let b = Image::filled(3, 2, 3, 0.5).unwrap();
        let err = contact_sheet(&[], &[SheetRow { label: "r".into(), images: vec![a, b] }]).unwrap_err();
        assert!(err.to_string().contains("image 1"), "{err}");
    }

    #[test]
    fn every_used_letter_has_its_own_glyph() {
        let unknown = glyph('\u{1}');
        for c in "abcdefghijklmnopqrstuvwxyz0123456789_-.,:/()=%".chars() {
            assert_ne!(glyph(c), unknown, "{c:?}");
        }
    }
}
