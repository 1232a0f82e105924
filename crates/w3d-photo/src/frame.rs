//! The authors' framing: crop to the object, scale its longest side to a fixed fraction of a
//! square frame, centre it, white behind it.

use image::imageops::FilterType;
use w3d_core::{Error, Image, Result};

/// Options of [`frame`]. Build from `Default` and chain `with_*` setters.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct FrameOptions {
    /// Side of the square output in pixels. Default 512: twice the model's 256² input, so
    /// its own resize only ever shrinks.
    pub size: u32,
    /// The object's longest side as a fraction of [`FrameOptions::size`]. Default 0.75, the
    /// Wonder3D / Wonder3D++ framing (192 of 256 pixels).
    pub fill: f32,
    /// Straight colour under fully transparent pixels (what a viewer without alpha shows).
    /// Default white, the model's background.
    pub background: [f32; 3],
    /// Upscaling by more than this factor re-sharpens the alpha edge to about
    /// 1.5 output pixels (see [`frame`]). Default 1.5.
    pub sharpen_above: f32,
}

impl Default for FrameOptions {
    fn default() -> Self {
        FrameOptions { size: 512, fill: 0.75, background: [1.0; 3], sharpen_above: 1.5 }
    }
}

impl FrameOptions {
    w3d_core::setters! {
        /// The same options with another output size.
        with_size(size: u32);
        /// The same options with another object fraction.
        with_fill(fill: f32);
        /// The same options with another background colour.
        with_background(background: [f32; 3]);
        /// The same options with another threshold for alpha re-sharpening.
        with_sharpen_above(sharpen_above: f32);
    }
}

/// A pixel rectangle of the input: columns `x..x + width`, rows `y..y + height`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub struct CropBox {
    /// Left column.
    pub x: u32,
    /// Top row.
    pub y: u32,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
}

impl CropBox {
    /// The box `x..x + width`, `y..y + height`.
    pub fn new(x: u32, y: u32, width: u32, height: u32) -> CropBox {
        CropBox { x, y, width, height }
    }
}

/// The result of [`frame`].
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct Framed {
    /// The framed RGBA image (straight alpha), `size × size`.
    pub rgba: Image,
    /// The object's box in the input (bounding box of alpha ≥ ½ / 255, the values an 8-bit
    /// file keeps).
    pub crop: CropBox,
    /// Output pixels per input pixel.
    pub scale: f32,
    /// Where the scaled crop sits in the output.
    pub placed: CropBox,
}

/// Alpha below this is "transparent" for the bounding box: it rounds to 0 in 8 bits.
const ALPHA_VISIBLE: f32 = 0.5 / 255.0;

/// The bounding box of the visible (alpha ≥ ½/255) pixels of an RGBA image, `None` when
/// every pixel is transparent.
pub fn alpha_bbox(rgba: &Image) -> Option<CropBox> {
    let w = rgba.width();
    let c = rgba.channels() as usize;
    let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0, 0);
    for (i, p) in rgba.data().chunks_exact(c).enumerate() {
        if p[c - 1] >= ALPHA_VISIBLE {
            let (x, y) = (i as u32 % w, i as u32 / w);
            (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x + 1), y1.max(y + 1));
        }
    }
    (x0 != u32::MAX).then(|| CropBox::new(x0, y0, x1 - x0, y1 - y0))
}

/// Frames an RGBA image (straight alpha masking the object) as Wonder3D++ expects: the
/// crop to the object's bounding box is scaled so its longest side is
/// [`FrameOptions::fill`] × [`FrameOptions::size`], centred on a square, transparent
/// canvas (straight colour [`FrameOptions::background`] where nothing is). Alpha is kept.
///
/// Resampling runs on premultiplied colour so no background colour bleeds into the edge.
/// Shrinking uses Lanczos3 (the sharpest of the common windowed-sinc filters, with the
/// antialiasing a big photo needs). Enlarging a small crop uses Catmull-Rom: it
/// interpolates the samples, is nearly as sharp as Lanczos3 but rings less on a hard alpha
/// edge (Lanczos3's overshoot draws a light halo when the model composites over white),
/// and needs no model. An enlarged edge is as blurry as the scale factor, so beyond
/// [`FrameOptions::sharpen_above`] the alpha is re-sharpened by a linear contrast around ½
/// that brings the edge back to about 1.5 output pixels (colour follows, premultiplied).
///
/// The framing is a fixed point of the model's own preparation (crop to alpha > 0, scale
/// the longest side to 75 %, centre): the visible box of the output is the placed box,
/// within a pixel where an edge row fades below ½/255 after resampling.
pub fn frame(rgba: &Image, options: &FrameOptions) -> Result<Framed> {
    if rgba.channels() != 4 {
        return Err(Error::invalid("image", format!("an RGBA image to frame, got {} channels", rgba.channels())));
    }
    if options.size == 0 || !(options.fill > 0.0 && options.fill <= 1.0) {
        return Err(Error::invalid(
            "frame options",
            format!("size ≥ 1 and fill in (0, 1], got size {} and fill {}", options.size, options.fill),
        ));
    }
    let crop = alpha_bbox(rgba)
        .ok_or_else(|| Error::invalid("image alpha", "a non-empty object mask (every pixel is transparent)"))?;
    let mut buf = image::Rgba32FImage::new(crop.width, crop.height);
    for (x, y, px) in buf.enumerate_pixels_mut() {
        let p = rgba.pixel(crop.x + x, crop.y + y);
        let a = p[3].clamp(0.0, 1.0);
        px.0 = [p[0].clamp(0.0, 1.0) * a, p[1].clamp(0.0, 1.0) * a, p[2].clamp(0.0, 1.0) * a, a];
    }
    let target = (options.fill * options.size as f32).round().max(1.0);
    let scale = target / crop.width.max(crop.height) as f32;
    let nw = ((crop.width as f32 * scale).round() as u32).clamp(1, options.size);
    let nh = ((crop.height as f32 * scale).round() as u32).clamp(1, options.size);
    let filter = if scale <= 1.0 { FilterType::Lanczos3 } else { FilterType::CatmullRom };
    let resized = image::imageops::resize(&buf, nw, nh, filter);
    // Re-sharpening gain: an edge 1 input pixel wide is `scale` output pixels wide.
    let gain = if scale > options.sharpen_above { scale / 1.5 } else { 1.0 };
    let (ox, oy) = ((options.size - nw) / 2, (options.size - nh) / 2);
    let s = options.size;
    let bg = options.background;
    let mut out = Image::new(s, s, 4, [bg[0], bg[1], bg[2], 0.0].repeat((s * s) as usize))?;
    for (x, y, px) in resized.enumerate_pixels() {
        let [r, g, b, a] = px.0;
        let a0 = a.clamp(0.0, 1.0);
        let a1 = ((a0 - 0.5) * gain + 0.5).clamp(0.0, 1.0);
        let dst = out.pixel_mut(ox + x, oy + y);
        if a1 < ALPHA_VISIBLE || a0 <= 1e-6 {
            continue; // stays transparent background
        }
        // Straight colour = premultiplied / alpha (clamped: resampling may overshoot).
        let straight = [r, g, b].map(|v| (v / a0).clamp(0.0, 1.0));
        dst.copy_from_slice(&[straight[0], straight[1], straight[2], a1]);
    }
    Ok(Framed { rgba: out, crop, scale, placed: CropBox::new(ox, oy, nw, nh) })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An RGBA image with an opaque `bw × bh` blue box at (`x`, `y`).
    fn boxed(w: u32, h: u32, x: u32, y: u32, bw: u32, bh: u32) -> Image {
        let mut img = Image::filled(w, h, 4, 0.0).unwrap();
        for yy in y..y + bh {
            for xx in x..x + bw {
                img.pixel_mut(xx, yy).copy_from_slice(&[0.1, 0.2, 0.9, 1.0]);
            }
        }
        img
    }

    /// Visible box after 8-bit quantisation.
    fn visible_box(img: &Image) -> CropBox {
        let mut q = img.clone();
        for p in q.data_mut().chunks_exact_mut(4) {
            p[3] = (p[3] * 255.0 + 0.5).floor() / 255.0;
        }
        alpha_bbox(&q).unwrap()
    }

    #[test]
    fn big_crop_is_shrunk_to_three_quarters_and_centred() {
        let img = boxed(900, 700, 100, 50, 600, 300);
        let f = frame(&img, &FrameOptions::default()).unwrap();
        assert_eq!(f.crop, CropBox::new(100, 50, 600, 300));
        assert_eq!((f.placed.width, f.placed.height), (384, 192));
        assert_eq!((f.placed.x, f.placed.y), (64, 160));
        let v = visible_box(&f.rgba);
        assert_eq!(v, f.placed, "the framing is its own fixed point");
        // Inside: the object's colour, opaque; outside: transparent white.
        let inside = f.rgba.pixel(256, 256);
        assert!(inside.iter().zip([0.1, 0.2, 0.9, 1.0]).all(|(a, b)| (a - b).abs() < 1e-5), "{inside:?}");
        assert_eq!(f.rgba.pixel(10, 10), &[1.0, 1.0, 1.0, 0.0]);
    }

    #[test]
    fn small_crop_is_enlarged_with_a_sharp_edge() {
        let img = boxed(40, 40, 10, 12, 20, 10);
        let f = frame(&img, &FrameOptions::default()).unwrap();
        assert!((f.scale - 384.0 / 20.0).abs() < 1e-4);
        let v = visible_box(&f.rgba);
        assert!(v.width.abs_diff(384) <= 2 && v.x.abs_diff(64) <= 1, "{v:?}");
        // Along the middle row the alpha goes 0 → 1 within 3 pixels.
        let row: Vec<f32> = (50..80).map(|x| f.rgba.pixel(x, 256)[3]).collect();
        let ramp = row.iter().filter(|&&a| a > 0.02 && a < 0.98).count();
        assert!(ramp <= 3, "{row:?}");
    }

    #[test]
    fn transparent_or_rgb_input_is_refused() {
        assert!(frame(&Image::filled(8, 8, 4, 0.0).unwrap(), &FrameOptions::default()).is_err());
        assert!(frame(&Image::filled(8, 8, 3, 0.5).unwrap(), &FrameOptions::default()).is_err());
    }
}
