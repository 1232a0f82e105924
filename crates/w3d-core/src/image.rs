//! Float images (`[H][W][C]`, row-major, origin top-left) and their PNG / EXR IO (feature
//! `io`).

#[cfg(feature = "io")]
use std::io::Write as _;
#[cfg(feature = "io")]
use std::path::Path;

#[cfg(feature = "io")]
use image::ImageEncoder as _;

use crate::{Error, Result};

/// A row-major float image with `channels` interleaved values per pixel, origin at the
/// top-left. What the values mean (sRGB colour, encoded normal, mask, depth) is stated by
/// whoever produces the image.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    width: u32,
    height: u32,
    channels: u32,
    data: Vec<f32>,
}

impl Image {
    /// An image from its data. Fails if a dimension is zero or `data.len()` is not
    /// `width · height · channels`.
    pub fn new(width: u32, height: u32, channels: u32, data: Vec<f32>) -> Result<Self> {
        if width == 0 || height == 0 || channels == 0 {
            return Err(Error::invalid(
                "image size",
                format!("non-zero width, height and channels, got {width}×{height}×{channels}"),
            ));
        }
        let expected = width as usize * height as usize * channels as usize;
        if data.len() != expected {
            return Err(Error::invalid(
                "image data",
                format!("{expected} values for {width}×{height}×{channels}, got {}", data.len()),
            ));
        }
        Ok(Image { width, height, channels, data })
    }

    /// An image with every value set to `value`. Fails on a zero dimension.
    pub fn filled(width: u32, height: u32, channels: u32, value: f32) -> Result<Self> {
        Self::new(width, height, channels, vec![value; width as usize * height as usize * channels as usize])
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Values per pixel.
    pub fn channels(&self) -> u32 {
        self.channels
    }

    /// All values, `[H][W][C]` row-major.
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// All values, mutable.
    pub fn data_mut(&mut self) -> &mut [f32] {
        &mut self.data
    }

    /// Consumes the image, returning its values.
    pub fn into_data(self) -> Vec<f32> {
        self.data
    }

    /// The values of pixel `(x, y)` (column, row). Panics if out of bounds.
    pub fn pixel(&self, x: u32, y: u32) -> &[f32] {
        let i = self.index(x, y);
        &self.data[i..i + self.channels as usize]
    }

    /// The values of pixel `(x, y)`, mutable. Panics if out of bounds.
    pub fn pixel_mut(&mut self, x: u32, y: u32) -> &mut [f32] {
        let i = self.index(x, y);
        let c = self.channels as usize;
        &mut self.data[i..i + c]
    }

    fn index(&self, x: u32, y: u32) -> usize {
        assert!(x < self.width && y < self.height, "pixel ({x}, {y}) outside {}×{}", self.width, self.height);
        (y as usize * self.width as usize + x as usize) * self.channels as usize
    }

    /// Fails unless the image is `width × height` with `channels` channels; `field` names
    /// the image in the error.
    pub fn expect_shape(&self, field: &str, width: u32, height: u32, channels: u32) -> Result<()> {
        if (self.width, self.height, self.channels) != (width, height, channels) {
            return Err(Error::invalid(
                field,
                format!(
                    "a {width}×{height} image with {channels} channels, got {}×{}×{}",
                    self.width, self.height, self.channels
                ),
            ));
        }
        Ok(())
    }

    /// This 3-channel image with `alpha` (1 channel, same size) appended as a fourth channel:
    /// e.g. a colour view and its mask as RGBA, ready for compositing.
    pub fn with_alpha(&self, alpha: &Image) -> Result<Image> {
        self.expect_shape("colour", self.width, self.height, 3)?;
        alpha.expect_shape("alpha", self.width, self.height, 1)?;
        let data = self.data.chunks_exact(3).zip(&alpha.data).flat_map(|(c, &a)| [c[0], c[1], c[2], a]).collect();
        Image::new(self.width, self.height, 4, data)
    }
}

/// PNG and OpenEXR files (feature `io`).
#[cfg(feature = "io")]
impl Image {
    /// Reads a PNG (8 or 16 bit, grey / grey+alpha / RGB / RGBA) as values in `[0, 1]`
    /// exactly as stored (no colour-space conversion). The channel count is the file's.
    pub fn read_png(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let decoded = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png)
            .map_err(|e| Error::format(path, "PNG data", format!("a readable PNG image ({e})")))?;
        let (w, h) = (decoded.width(), decoded.height());
        let channels = decoded.color().channel_count() as u32;
        let data: Vec<f32> = match decoded {
            image::DynamicImage::ImageLuma8(b) => b.into_raw().into_iter().map(|v| v as f32 / 255.0).collect(),
            image::DynamicImage::ImageLumaA8(b) => b.into_raw().into_iter().map(|v| v as f32 / 255.0).collect(),
            image::DynamicImage::ImageRgb8(b) => b.into_raw().into_iter().map(|v| v as f32 / 255.0).collect(),
            image::DynamicImage::ImageRgba8(b) => b.into_raw().into_iter().map(|v| v as f32 / 255.0).collect(),
            image::DynamicImage::ImageLuma16(b) => b.into_raw().into_iter().map(|v| v as f32 / 65535.0).collect(),
            image::DynamicImage::ImageLumaA16(b) => b.into_raw().into_iter().map(|v| v as f32 / 65535.0).collect(),
            image::DynamicImage::ImageRgb16(b) => b.into_raw().into_iter().map(|v| v as f32 / 65535.0).collect(),
            image::DynamicImage::ImageRgba16(b) => b.into_raw().into_iter().map(|v| v as f32 / 65535.0).collect(),
            other => {
                return Err(Error::format(
                    path,
                    "PNG colour type",
                    format!("8- or 16-bit grey/RGB(A), got {:?}", other.color()),
                ));
            }
        };
        Image::new(w, h, channels, data).map_err(|e| e.in_file(path))
    }

    /// Reads a PNG and requires `channels` channels (`field` names the image in errors).
    pub fn read_png_channels(path: impl AsRef<Path>, channels: u32) -> Result<Self> {
        let path = path.as_ref();
        let img = Self::read_png(path)?;
        if img.channels != channels {
            return Err(Error::format(path, "PNG channels", format!("{channels} channels, got {}", img.channels)));
        }
        Ok(img)
    }

    /// Encodes an 8-bit PNG (1, 2, 3 or 4 channels) in memory. Values are clamped to
    /// `[0, 1]` and rounded (`v·255 + 0.5`); NaN is an error, not a silent zero.
    pub fn encode_png(&self) -> Result<Vec<u8>> {
        let color = match self.channels {
            1 => image::ExtendedColorType::L8,
            2 => image::ExtendedColorType::La8,
            3 => image::ExtendedColorType::Rgb8,
            4 => image::ExtendedColorType::Rgba8,
            c => return Err(Error::invalid("image channels", format!("1 to 4 channels for PNG, got {c}"))),
        };
        if let Some(i) = self.data.iter().position(|v| v.is_nan()) {
            return Err(Error::invalid(format!("image value {i}"), "a number, got NaN"));
        }
        let bytes: Vec<u8> = self.data.iter().map(|v| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8).collect();
        let mut png = Vec::new();
        image::codecs::png::PngEncoder::new(&mut png)
            .write_image(&bytes, self.width, self.height, color)
            .map_err(|e| Error::invalid("image", format!("an encodable PNG ({e})")))?;
        Ok(png)
    }

    /// Writes an 8-bit PNG (1, 2, 3 or 4 channels) atomically; see [`Image::encode_png`].
    pub fn write_png(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let png = self.encode_png()?;
        crate::io::write_atomic(path, |w| w.write_all(&png).map_err(|e| Error::io(path, e)))
    }

    /// Reads the first RGBA layer of an OpenEXR file as a 4-channel f32 image (missing
    /// channels read as 0, alpha as 1).
    pub fn read_exr(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let image = exr::prelude::read_first_rgba_layer_from_file(
            path,
            |resolution, _| (resolution.width(), vec![0.0f32; resolution.width() * resolution.height() * 4]),
            |(width, data), pos, (r, g, b, a): (f32, f32, f32, f32)| {
                let i = (pos.y() * *width + pos.x()) * 4;
                data[i..i + 4].copy_from_slice(&[r, g, b, a]);
            },
        )
        .map_err(|e| match e {
            exr::error::Error::Io(io) => Error::io(path, io),
            other => Error::format(path, "EXR data", format!("a readable RGBA OpenEXR image ({other})")),
        })?;
        let size = image.layer_data.size;
        let (_, data) = image.layer_data.channel_data.pixels;
        Image::new(size.width() as u32, size.height() as u32, 4, data).map_err(|e| e.in_file(path))
    }

    /// Writes the image as a 32-bit float RGBA OpenEXR file, atomically. 1-channel images
    /// are written as grey (R = G = B) with alpha 1, 3-channel images with alpha 1.
    pub fn write_exr(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let c = self.channels as usize;
        if !matches!(c, 1 | 3 | 4) {
            return Err(Error::invalid("image channels", format!("1, 3 or 4 channels for EXR, got {c}")));
        }
        let w = self.width as usize;
        let rgba = |x: usize, y: usize| -> (f32, f32, f32, f32) {
            let p = &self.data[(y * w + x) * c..(y * w + x + 1) * c];
            match c {
                1 => (p[0], p[0], p[0], 1.0),
                3 => (p[0], p[1], p[2], 1.0),
                _ => (p[0], p[1], p[2], p[3]),
            }
        };
        let channels = exr::prelude::SpecificChannels::rgba(|exr::math::Vec2(x, y)| rgba(x, y));
        let image = exr::prelude::Image::from_channels((w, self.height as usize), channels);
        crate::io::write_atomic(path, |file| {
            use exr::prelude::WritableImage as _;
            image.write().to_buffered(file).map_err(|e| match e {
                exr::error::Error::Io(io) => Error::io(path, io),
                other => Error::format(path, "EXR encoding", other.to_string()),
            })
        })
    }
}

/// sRGB-encoded value in `[0, 1]` → linear.
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 { v / 12.92 } else { ((v + 0.055) / 1.055).powf(2.4) }
}

/// Linear value in `[0, 1]` → sRGB-encoded.
pub fn linear_to_srgb(v: f32) -> f32 {
    if v <= 0.0031308 { v * 12.92 } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 }
}
