//! **w3d-photo**: a real photo of an object in, the RGBA image Wonder3D++ expects out —
//! background removed (or the image's own alpha used), cropped to the object, its longest
//! side 75 % of a square frame, centred, white behind it. No model, no download: the
//! background removal is a classical one for product-style photos (plain, graded or softly
//! shadowed backgrounds): a robust background surface fitted to the border, shadow-aware
//! likelihoods, GrabCut-style graph cuts with our own max-flow, and a guided-filter matte
//! at the boundary. Every automatic mask comes with a [`Confidence`] and its reasons;
//! [`prepare`] refuses a photo it cannot trust and says why.
//!
//! ```
//! use w3d_core::Image;
//! use w3d_photo::{MaskSource, PrepareOptions, prepare};
//!
//! // A "photo": a shaded orange disc on a light grey backdrop, no alpha.
//! let (w, h) = (160u32, 120u32);
//! let mut photo = Image::filled(w, h, 3, 0.88)?;
//! for y in 0..h {
//!     for x in 0..w {
//!         let r = ((x as f32 - 90.0).powi(2) + (y as f32 - 60.0).powi(2)).sqrt();
//!         if r < 30.0 {
//!             photo.pixel_mut(x, y).copy_from_slice(&[0.95 - r / 100.0, 0.45, 0.1]);
//!         }
//!     }
//! }
//! let prepared = prepare(&photo, &PrepareOptions::default())?;
//! assert_eq!(prepared.source, MaskSource::Segmented);
//! assert!(prepared.confidence.score > 0.9, "{}", prepared.confidence.summary());
//! // Framed: 512², the 60-pixel disc now 384 pixels wide, centred, alpha kept.
//! assert_eq!((prepared.rgba.width(), prepared.rgba.height(), prepared.rgba.channels()), (512, 512, 4));
//! assert_eq!(prepared.rgba.pixel(256, 256)[3], 1.0);
//! assert_eq!(prepared.rgba.pixel(20, 256)[3], 0.0);
//! // The mask at the photo's own resolution.
//! assert_eq!(prepared.mask.pixel(90, 60)[0], 1.0);
//! assert_eq!(prepared.mask.pixel(10, 10)[0], 0.0);
//! # Ok::<(), w3d_core::Error>(())
//! ```
//!
//! The parts work alone too: [`remove_background`] (photo → soft mask + confidence),
//! [`frame`] (RGBA → the framed RGBA), and [`eval`] (composites over known backdrops and
//! mask scores). The method, its measured accuracy and the framing are described in
//! `docs/input.md`.

// Layers, bottom-up: each group imports only from itself and the groups above it.
// Building blocks: Gaussian mixtures, max-flow, framing.
mod frame;
mod gmm;
mod maxflow;

// The guided-filter matte.
mod matte;

// Background removal.
mod segment;

// Whole jobs: photo → the model's input, and the evaluation on composites.
pub mod eval;
mod input;

pub use frame::{CropBox, FrameOptions, Framed, alpha_bbox, frame};
pub use input::{Framing, MaskSource, PrepareOptions, Prepared, has_meaningful_alpha, prepare};
pub use segment::{Confidence, Issue, Measures, Reason, SegmentOptions, Segmentation, remove_background};
