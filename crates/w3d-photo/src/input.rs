//! [`prepare`]: a photo or an RGBA image → the model's input (the image's own alpha or
//! automatic background removal, then the framing), with [`PrepareOptions`] and the
//! [`Prepared`] result.

use w3d_core::{Error, Image, Result};

use crate::frame::{CropBox, FrameOptions, frame};
use crate::segment::{Confidence, SegmentOptions, remove_background, to_rgb};

/// Options of [`prepare`]. Build from `Default` and chain `with_*` setters.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct PrepareOptions {
    /// How to remove a background when the image has no alpha.
    pub segment: SegmentOptions,
    /// How to frame the object.
    pub frame: FrameOptions,
    /// Crop and frame (default). Off, the output keeps the input's frame and size (the
    /// mask can then be compared with a known alpha).
    pub crop: bool,
    /// Automatic masks less confident than this are refused with an error naming the
    /// reasons (default 0.5; 0 accepts everything).
    pub min_confidence: f32,
}

impl Default for PrepareOptions {
    fn default() -> Self {
        PrepareOptions {
            segment: SegmentOptions::default(),
            frame: FrameOptions::default(),
            crop: true,
            min_confidence: 0.5,
        }
    }
}

impl PrepareOptions {
    w3d_core::setters! {
        /// The same options with other segmentation options.
        with_segment(segment: SegmentOptions);
        /// The same options with other framing options.
        with_frame(frame: FrameOptions);
        /// The same options with cropping on or off.
        with_crop(crop: bool);
        /// The same options with another confidence threshold.
        with_min_confidence(min_confidence: f32);
    }
}

/// Where the object's mask came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum MaskSource {
    /// The image's own alpha channel.
    Alpha,
    /// Automatic background removal ([`remove_background`]).
    Segmented,
}

impl MaskSource {
    /// A short snake_case name.
    pub fn name(self) -> &'static str {
        match self {
            MaskSource::Alpha => "alpha",
            MaskSource::Segmented => "segmented",
        }
    }
}

/// The result of [`prepare`].
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct Prepared {
    /// The image for the model: RGBA with straight alpha; framed (`frame.size` square)
    /// unless cropping was off, then the input's size.
    pub rgba: Image,
    /// The object's mask at the input's resolution (1 channel, 1 = object).
    pub mask: Image,
    /// Where the mask came from.
    pub source: MaskSource,
    /// How far to trust the mask ([`Confidence::certain`] for the image's own alpha).
    pub confidence: Confidence,
    /// The framing: crop box in the input, scale and placement (`None` without cropping).
    pub framing: Option<Framing>,
}

/// Where the object went in [`prepare`]'s framing.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct Framing {
    /// The object's box in the input.
    pub crop: CropBox,
    /// Output pixels per input pixel (above 1: the crop was enlarged).
    pub scale: f32,
    /// Where the scaled crop sits in the output.
    pub placed: CropBox,
}

/// Whether an image carries an alpha channel worth using: 2 or 4 channels, with at least
/// one pixel below half opacity. An RGBA photo whose alpha is all (nearly) opaque is
/// treated as RGB.
pub fn has_meaningful_alpha(image: &Image) -> bool {
    let c = image.channels() as usize;
    matches!(c, 2 | 4) && image.data().chunks_exact(c).any(|p| p[c - 1] < 0.5)
}

/// Turns a photo or an RGBA image into the model's input: the image's own alpha when it
/// has a meaningful one ([`has_meaningful_alpha`]), else [`remove_background`] (refused
/// below [`PrepareOptions::min_confidence`] with the reasons); then, unless
/// [`PrepareOptions::crop`] is off, [`frame`].
///
/// `image` has 1 (grey), 2 (grey + alpha), 3 (RGB) or 4 (RGBA) channels with sRGB values in
/// `[0, 1]`, as [`Image::read`] returns them.
pub fn prepare(image: &Image, options: &PrepareOptions) -> Result<Prepared> {
    let c = image.channels() as usize;
    let rgb = to_rgb(image)?;
    let (mask, source, confidence) = if has_meaningful_alpha(image) {
        let alpha: Vec<f32> = image.data().chunks_exact(c).map(|p| p[c - 1].clamp(0.0, 1.0)).collect();
        if alpha.iter().all(|&a| a < 0.5 / 255.0) {
            return Err(Error::invalid("image alpha", "some visible pixel (every pixel is fully transparent)"));
        }
        (Image::new(image.width(), image.height(), 1, alpha)?, MaskSource::Alpha, Confidence::certain())
    } else {
        let seg = remove_background(image, &options.segment)?;
        if seg.confidence.score < options.min_confidence {
            return Err(Error::invalid(
                "image background",
                format!(
                    "a plain, graded or softly shadowed background that can be removed automatically, but \
                     the removal's confidence is {:.2}, below {:.2}: {}. Pass an RGBA image whose alpha \
                     channel masks the object instead (background removed in an image editor or another tool)",
                    seg.confidence.score,
                    options.min_confidence,
                    seg.confidence.summary()
                ),
            ));
        }
        (seg.alpha, MaskSource::Segmented, seg.confidence)
    };
    let rgba_data: Vec<f32> = rgb.iter().zip(mask.data()).flat_map(|(p, &a)| [p[0], p[1], p[2], a]).collect();
    let rgba = Image::new(image.width(), image.height(), 4, rgba_data)?;
    let (rgba, framing) = if options.crop {
        let f = frame(&rgba, &options.frame)?;
        (f.rgba, Some(Framing { crop: f.crop, scale: f.scale, placed: f.placed }))
    } else {
        (rgba, None)
    };
    Ok(Prepared { rgba, mask, source, confidence, framing })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opaque_alpha_is_treated_as_rgb_and_real_alpha_is_used() {
        let mut img = Image::filled(64, 64, 4, 1.0).unwrap();
        assert!(!has_meaningful_alpha(&img));
        for y in 20..40 {
            for x in 24..44 {
                img.pixel_mut(x, y).copy_from_slice(&[0.1, 0.3, 0.8, 1.0]);
            }
        }
        // Opaque: segmented (blue square on white).
        let p = prepare(&img, &PrepareOptions::default().with_crop(false)).unwrap();
        assert_eq!(p.source, MaskSource::Segmented);
        assert_eq!((p.rgba.width(), p.rgba.height()), (64, 64));
        assert_eq!(p.mask.pixel(30, 30)[0], 1.0);
        assert_eq!(p.mask.pixel(5, 5)[0], 0.0);
        // Real alpha: used as it is, whatever the colours say.
        for y in 0..64 {
            for x in 0..64 {
                img.pixel_mut(x, y)[3] = if (10..20).contains(&x) && (10..30).contains(&y) { 1.0 } else { 0.0 };
            }
        }
        let p = prepare(&img, &PrepareOptions::default()).unwrap();
        assert_eq!(p.source, MaskSource::Alpha);
        assert_eq!(p.confidence.score, 1.0);
        let f = p.framing.unwrap();
        assert_eq!(f.crop, CropBox::new(10, 10, 10, 20));
        assert_eq!((p.rgba.width(), f.placed.height), (512, 384));
    }

    #[test]
    fn one_pixel_photo_is_refused_not_a_panic() {
        for (w, h, c) in [(1, 1, 3), (1, 1, 1), (2, 1, 4), (1, 3, 2)] {
            let img = Image::filled(w, h, c, 0.5).unwrap();
            let err = prepare(&img, &PrepareOptions::default()).unwrap_err().to_string();
            assert!(err.contains("RGBA") && err.contains("no object"), "{w}×{h}×{c}: {err}");
        }
    }

    #[test]
    fn fully_transparent_and_cluttered_inputs_are_refused_with_reasons() {
        let clear = Image::filled(16, 16, 4, 0.0).unwrap();
        let err = prepare(&clear, &PrepareOptions::default()).unwrap_err().to_string();
        assert!(err.contains("transparent"), "{err}");
        // Random clutter everywhere: no smooth background.
        let data: Vec<f32> =
            (0..96 * 96 * 3u32).map(|i| ((i.wrapping_mul(2_654_435_761) >> 8) % 256) as f32 / 255.0).collect();
        let noise = Image::new(96, 96, 3, data).unwrap();
        let err = prepare(&noise, &PrepareOptions::default()).unwrap_err().to_string();
        assert!(err.contains("RGBA") && err.contains("cluttered"), "{err}");
        // With no threshold the same photo passes, with its low confidence.
        let p = prepare(&noise, &PrepareOptions::default().with_min_confidence(0.0).with_crop(false)).unwrap();
        assert!(p.confidence.score < 0.5, "{:?}", p.confidence);
    }
}
